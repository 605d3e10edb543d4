"""The policies' observation layouts, each declared once as named fields.

The environment's observation is the thesis's 9 numbers (:data:`OBS_LAYOUT`). A policy
takes one of seven layouts (:data:`LAYOUTS`):

* ``thesis``: the thesis's 9 numbers (position, orientation quaternion, last command).
* ``context``: those 9, then what the deployed host also knows (:data:`CONTEXT_FIELDS`):
  the design it built (``x, y, z, l``, m), the steps left in the episode as a fraction
  of the episode (1 before the first step), and the previous step's 9 thesis numbers
  (the current ones again before the first step). A policy with this input is told the
  body it drives, how much time is left, and what its last action did.
* ``memory``: ``context``, then ``goto``'s memory of the episode (:data:`MEMORY_FIELDS`,
  :class:`tumblebot.sim.control.goto.MotionMemory`): the running estimates of a drive step's
  length (m) and of each spin's yaw change (rad), learnt from every step so far, with the
  action of each step read from the command the next observation carries.
* ``residual``: ``memory``, then the action ``goto`` itself would take now
  (:data:`RESIDUAL_FIELDS`, each leg's command 0/1/2; :class:`tumblebot.sim.control.goto.GotoController`
  with the settings in :data:`RESIDUAL_GOTO`, told every step the action actually taken).
  A policy with this input starts from the hand-written controller's choice and learns
  where to deviate from it (residual policy learning).
* ``dual``: ``residual``, then the action of a second ``goto`` with the settings in
  :data:`DUAL_GOTO` (:data:`DUAL_FIELDS`), which suit some bodies better and others worse;
  a policy with this input, which also knows the design, can follow whichever suits the
  body it drives (:mod:`tumblebot.training.choice`).
* ``dual-plan``: the fields of ``dual``, computed by two ``goto`` with ``plan``'s steadier
  estimates (:data:`PLAN_GOTO`, the first one's also giving the memory fields, and
  :data:`PLAN_DUAL_GOTO`): the input of a student of ``plan``, the stronger hand-written
  controller.
* ``tri-plan``: the fields of ``dual-plan``, then the action of a third ``goto`` with
  ``plan``'s estimates and the wider turning of :data:`PLAN_SHORT_GOTO`
  (:data:`TRI_FIELDS`), which drives bodies whose legs barely tumble them better than
  ``plan`` does.

Code that reads a part of an observation asks for it by name (:func:`field_index`,
:func:`fields_slice`), never by a hand-counted offset. This module imports nothing of
the simulator: the environment, ``goto``, the ONNX runner and training all import it.
"""

from __future__ import annotations

from typing import Any

#: The thesis observation, the environment's: position, orientation quaternion, last command.
OBS_LAYOUT: tuple[str, ...] = ("px", "py", "pz", "qx", "qy", "qz", "qw", "cmd_right", "cmd_left")
POSITION, QUATERNION, COMMAND = slice(0, 3), slice(3, 7), slice(7, 9)  #: where each part lies in it
CONTEXT_FIELDS: tuple[str, ...] = ("design_x", "design_y", "design_z", "design_l", "steps_left",
                                   *(f"prev_{name}" for name in OBS_LAYOUT))
MEMORY_FIELDS: tuple[str, ...] = ("memory_step_length", "memory_spin_positive", "memory_spin_negative")
RESIDUAL_FIELDS: tuple[str, ...] = ("goto_right", "goto_left")
DUAL_FIELDS: tuple[str, ...] = ("goto2_right", "goto2_left")
TRI_FIELDS: tuple[str, ...] = ("goto3_right", "goto3_left")
LAYOUTS: dict[str, tuple[str, ...]] = {"thesis": OBS_LAYOUT, "context": OBS_LAYOUT + CONTEXT_FIELDS,
                                       "memory": OBS_LAYOUT + CONTEXT_FIELDS + MEMORY_FIELDS,
                                       "residual": OBS_LAYOUT + CONTEXT_FIELDS + MEMORY_FIELDS + RESIDUAL_FIELDS,
                                       "dual": OBS_LAYOUT + CONTEXT_FIELDS + MEMORY_FIELDS + RESIDUAL_FIELDS
                                       + DUAL_FIELDS}
#: The settings of the ``goto`` whose action a ``residual`` policy is given, pinned here
#: (not goto's defaults) so that a trained policy's input never changes under it.
RESIDUAL_GOTO: dict[str, Any] = {"turn_tolerance": 0.4, "stop_fraction": 0.5, "margin": 0.02, "memory": 0.5,
                                   "spin_steps_left": 2}
#: The second ``goto`` a ``dual`` policy is shown: the settings that gain on the thesis's
#: robots and on medium legs and lose on short legs (``reports/policy-headroom``), pinned.
DUAL_GOTO: dict[str, Any] = {**RESIDUAL_GOTO, "turn_tolerance": 0.3, "spin_steps_left": 4}
#: ``plan``'s settings (:data:`tumblebot.sim.control.goto.NAVIGATORS`), pinned for the
#: ``dual-plan`` layout's first goto, and its second: ``plan``'s estimates with the turning
#: of :data:`DUAL_GOTO`, which the thesis's robots prefer.
PLAN_GOTO: dict[str, Any] = {**RESIDUAL_GOTO, "memory": 0.25, "spin_steps_left": 3}
PLAN_DUAL_GOTO: dict[str, Any] = {**PLAN_GOTO, "turn_tolerance": 0.3, "spin_steps_left": 4}
#: ``plan``'s estimates with a wider turning tolerance (it drives before the body faces the
#: goal as closely), which gains on bodies with short legs (l / r below about 1.2) and loses
#: on the rest: the ``tri-plan`` layout's third goto, and the ``plan-short`` controller.
PLAN_SHORT_GOTO: dict[str, Any] = {**PLAN_GOTO, "turn_tolerance": 0.6}
LAYOUTS["dual-plan"] = LAYOUTS["dual"]
LAYOUTS["tri-plan"] = LAYOUTS["dual"] + TRI_FIELDS
#: The layouts given goto's actions: the settings of each goto, in the order of their fields
#: (the first one's running estimates are the memory fields).
GOTO_SETTINGS: dict[str, tuple[dict[str, Any], ...]] = {"residual": (RESIDUAL_GOTO,),
                                                        "dual": (RESIDUAL_GOTO, DUAL_GOTO),
                                                        "dual-plan": (PLAN_GOTO, PLAN_DUAL_GOTO),
                                                        "tri-plan": (PLAN_GOTO, PLAN_DUAL_GOTO, PLAN_SHORT_GOTO)}
#: the layouts shown several gotos' actions, whose teacher chooses among them per body
#: (:mod:`tumblebot.training.choice`)
CHOICE_LAYOUTS: tuple[str, ...] = tuple(name for name, gotos in GOTO_SETTINGS.items() if len(gotos) >= 2)


def teacher_name(layout: str) -> str:
    """The hand-written controller a layout's first goto setting is, by its ``--gait`` name:
    ``plan`` for ``dual-plan`` and ``tri-plan`` (whose gotos take plan's estimates),
    ``goto`` otherwise."""
    return "plan" if GOTO_SETTINGS.get(layout, (None,))[0] is PLAN_GOTO else "goto"


EPISODE_STEPS = 20  #: the episode the ``steps_left`` input counts down (thesis: 20 steps of 1 s)
ACTION_LAYOUT: dict[str, Any] = {"motors": ["right", "left"], "values": {"0": "reverse", "1": "stop", "2": "forward"}}




def field_index(layout: str, name: str) -> int:
    """Where the field ``name`` lies in ``layout`` (``KeyError`` names both if it is not there)."""
    fields = LAYOUTS[layout]
    if name not in fields:
        raise KeyError(f"layout {layout!r} has no field {name!r}")
    return fields.index(name)


def fields_slice(layout: str, first: str, last: str) -> slice:
    """The fields from ``first`` to ``last`` (inclusive) of ``layout``, as a slice."""
    start, stop = field_index(layout, first), field_index(layout, last)
    if stop < start:
        raise KeyError(f"field {last!r} comes before {first!r} in layout {layout!r}")
    return slice(start, stop + 1)
