"""Running an exported policy: an ONNX file plus its model card, through onnxruntime.

Every inference outside training (evaluation, optimisation, the host) goes through
:class:`OnnxPolicy`; torch is not needed. The model card (``POLICY.json`` beside
``POLICY.onnx``) says which task and observation layout the network expects, and holds
the SHA-256 of the ONNX file; loading checks all three.

The observation layouts are declared in :mod:`tumblebot.sim.observation` (and re-exported
here for the callers that load policies).

Callers always hand :meth:`OnnxPolicy.act` the thesis observation; the policy builds the
rest itself (:class:`ObservationContext`), given the design at :meth:`OnnxPolicy.reset`,
which every episode or trial starts with.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from tumblebot.sim.control import features
from tumblebot.sim.control.goto import GotoConfig, GotoController, MotionMemory, heading
from tumblebot.sim.errors import SimError
from tumblebot.sim.observation import (
    ACTION_LAYOUT,
    COMMAND,
    CONTEXT_FIELDS,
    DUAL_FIELDS,
    DUAL_GOTO,
    EPISODE_STEPS,
    GOTO_SETTINGS,
    LAYOUTS,
    MEMORY_FIELDS,
    OBS_LAYOUT,
    POSITION,
    QUATERNION,
    RESIDUAL_FIELDS,
    RESIDUAL_GOTO,
)
from tumblebot.sim.world.tasks import same_goal

__all__ = ["ACTION_LAYOUT", "COMMAND", "CONTEXT_FIELDS", "DUAL_FIELDS", "DUAL_GOTO", "EPISODE_STEPS", "LAYOUTS",
           "MEMORY_FIELDS", "OBS_LAYOUT", "POSITION", "QUATERNION", "RESIDUAL_FIELDS", "RESIDUAL_GOTO",
           "ObservationContext", "OnnxPolicy", "PolicyError", "bundled_policy", "card_path", "layout_named",
           "sha256_of"]

class PolicyError(SimError):
    """A policy file that is missing, corrupt, or for another task or observation layout."""


def card_path(onnx_path: Path) -> Path:
    return onnx_path.with_suffix(".json")


def sha256_of(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def bundled_policy(task: str, layout: str | None = None) -> Path:
    """The policy shipped with tumblebot for ``task`` (``policies/TASK.onnx``, the best
    one). With ``layout="thesis"``, the one whose input is the thesis's 9 numbers (the
    thesis reproduction's): ``policies/TASK-thesis.onnx`` where the best one takes more,
    else the best one itself."""
    import tumblebot.policies

    folder = Path(tumblebot.policies.__file__).parent
    if layout == "thesis" and (folder / f"{task}-thesis.onnx").is_file():
        return folder / f"{task}-thesis.onnx"
    return folder / f"{task}.onnx"


def layout_named(fields: Sequence[str], name: object = None) -> str:
    """The name of the layout whose fields are ``fields``; :class:`PolicyError` if none.
    ``name`` is the layout a model card names (cards before ``dual-plan`` may name none):
    two layouts can share their fields and differ in what computes them (``dual`` and
    ``dual-plan``), so a named layout is taken as named, and must have these fields."""
    if name is not None:
        if not isinstance(name, str) or name not in LAYOUTS or tuple(fields) != LAYOUTS[name]:
            raise PolicyError(f"observation layout {name!r} with fields {list(fields)!r} is none of the known "
                              f"layouts ({', '.join(LAYOUTS)})")
        return str(name)
    for name, layout in LAYOUTS.items():
        if tuple(fields) == layout:
            return name
    raise PolicyError(f"observation layout {list(fields)!r} is none of the known layouts ("
                      + "; ".join(f"{n}: {list(f)}" for n, f in LAYOUTS.items()) + ")")


class ObservationContext:
    """Builds a policy's input in ``layout`` from the thesis observation, step by step.

    ``reset(design)`` starts an episode; each call then takes the thesis observation
    before the next step and returns the policy input (for ``thesis``, the observation
    itself). The step count, the previous observation and (``memory``) the motion
    estimates are its own memory, so it must see every step of the episode, in order.
    """

    def __init__(self, layout: str = "thesis", episode_steps: int = EPISODE_STEPS) -> None:
        if layout not in LAYOUTS:
            raise PolicyError(f"unknown observation layout {layout!r} (known: {', '.join(LAYOUTS)})")
        if episode_steps < 1:
            raise PolicyError(f"episode_steps={episode_steps} must be at least 1")
        self.layout = layout
        self.size = len(LAYOUTS[layout])
        self.episode_steps = episode_steps
        self._design: np.ndarray | None = None
        self._previous: np.ndarray | None = None
        self._motion: Any = None
        self._gotos: list[GotoController] = []  # the first one's estimates are the memory fields
        if layout == "memory":
            self._motion = MotionMemory()
        elif layout in GOTO_SETTINGS:
            self._gotos = [GotoController(GotoConfig(episode_steps=episode_steps, **settings))
                           for settings in GOTO_SETTINGS[layout]]
        self.step = 0

    @property
    def needs_design(self) -> bool:
        return self.layout != "thesis"

    def reset(self, design: Sequence[float] | None = None) -> None:
        if self.needs_design:
            if design is None:
                raise PolicyError("this policy is conditioned on the design: give the robot's "
                                  "(x, y, z, l) when the episode or trial starts")
            values = np.asarray([float(v) for v in design], dtype=np.float32)
            if values.shape != (4,) or not np.all(np.isfinite(values)) or np.any(values <= 0):
                raise PolicyError(f"design {list(design)!r} must be four positive lengths (x, y, z, l) in m")
            self._design = values
        self._previous = None
        if self._motion is not None:
            self._motion.reset()
        for goto in self._gotos:
            goto.reset()
        self.step = 0

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs, dtype=np.float32).reshape(-1)
        if obs.shape != (len(OBS_LAYOUT),):
            raise PolicyError(f"observation has {obs.size} numbers, not the thesis's {len(OBS_LAYOUT)}")
        if self.layout == "thesis":
            return obs
        if self._design is None:
            raise PolicyError("call reset(design) at the start of every episode or trial")
        previous = obs if self._previous is None else self._previous
        steps_left = max(self.episode_steps - self.step, 0) / self.episode_steps
        step, self._previous = self.step, obs
        self.step += 1
        time_left = np.array([steps_left], dtype=np.float32)
        parts = [obs, self._design, time_left, previous]
        if self._motion is not None:
            parts.append(self._remember(obs, first=step == 0))
        if self._gotos:
            parts.extend(self._propose(obs, step))
        return np.concatenate(parts).astype(np.float32)

    @staticmethod
    def _taken(obs: np.ndarray) -> tuple[int, int]:
        """The action of the step before ``obs``: the command it carries (−1, 0, 1 per
        leg → 0, 1, 2; plain floats: NumPy's clip on two numbers was a third of the cost)."""
        right, left = (float(v) for v in obs[COMMAND])
        return _leg_action(right), _leg_action(left)

    def _remember(self, obs: np.ndarray, first: bool) -> np.ndarray:
        """The motion estimates after this observation."""
        action = None if first else self._taken(obs)
        self._motion.observe(obs[POSITION][:2].astype(float), heading(obs[QUATERNION]), action)
        return np.asarray(self._motion.as_array(), dtype=np.float32)

    def _propose(self, obs: np.ndarray, step: int) -> list[np.ndarray]:
        """goto's motion estimates and its action now (``dual``, ``tri-plan``: then each
        later goto's action), each told what was actually done last step."""
        actions = []
        taken = self._taken(obs) if step > 0 else None
        as_float = obs.astype(float)
        for goto in self._gotos:
            if taken is not None:
                goto.taken(taken)
            actions.append(np.asarray(goto.act(as_float, min(step, self.episode_steps - 1)), dtype=np.float32))
        return [np.asarray(self._gotos[0].motion.as_array(), dtype=np.float32), *actions]


def _leg_action(command: float) -> int:
    """A leg's command (−1, 0, 1) as its action (0, 1, 2); a command that is not a number, stop."""
    return min(max(round(command) + 1, 0), 2) if math.isfinite(command) else 1


class OnnxPolicy:
    """A deterministic policy: ``act(obs) -> (right, left)`` in {0, 1, 2}.

    Args:
        path: the ``.onnx`` file; its model card must sit beside it.
        task: if given, the card's task must match.
    """

    def __init__(self, path: Path, task: str | None = None) -> None:
        path = Path(path)
        if not path.is_file():
            raise PolicyError(f"policy file {path} does not exist")
        cpath = card_path(path)
        if not cpath.is_file():
            raise PolicyError(f"policy {path} has no model card {cpath.name} beside it")
        try:
            card = json.loads(cpath.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise PolicyError(f"model card {cpath} is not valid JSON: {exc}") from None
        if not isinstance(card, dict):
            raise PolicyError(f"model card {cpath} must hold a JSON object")
        if task is not None and card.get("task") != task:
            raise PolicyError(f"policy {path} was trained for task {card.get('task')!r}, not {task!r}")
        training = card.get("training_config")
        trained = training.get("task") if isinstance(training, dict) else None
        if trained is not None and not same_goal(str(trained), str(card.get("task"))):
            raise PolicyError(f"model card {cpath} says task {card.get('task')!r} but its training config "
                              f"says {trained!r}: the card does not describe this policy")
        observation = card.get("observation")
        if not isinstance(observation, dict) or not isinstance(observation.get("fields"), list):
            raise PolicyError(f"model card {cpath} has no observation layout (observation.fields)")
        try:
            self.layout = layout_named(observation.get("fields", ()), observation.get("layout"))
        except PolicyError as exc:
            raise PolicyError(f"policy {path}: {exc}") from None
        graph = path.read_bytes()  # read once: the bytes hashed are the bytes run
        digest = hashlib.sha256(graph).hexdigest()
        if card.get("onnx_sha256") != digest:
            raise PolicyError(f"policy {path} does not match its model card (SHA-256 {digest[:12]}…, "
                              f"card says {str(card.get('onnx_sha256'))[:12]}…): corrupt or replaced file")
        import onnxruntime as ort

        options = ort.SessionOptions()
        options.intra_op_num_threads = 1
        options.inter_op_num_threads = 1
        try:
            self.session = ort.InferenceSession(graph, options, providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own exception types
            raise PolicyError(f"policy {path} cannot be loaded by onnxruntime: {exc}") from None
        self.path = path
        self.card: dict[str, Any] = card
        self.task: str = str(card.get("task"))
        inputs = self.session.get_inputs()
        if len(inputs) != 1 or inputs[0].shape[-1] != len(LAYOUTS[self.layout]):
            raise PolicyError(f"policy {path}'s graph does not take the {self.layout} layout's "
                              f"{len(LAYOUTS[self.layout])} numbers its card declares")
        self._input = inputs[0].name
        self.context = ObservationContext(self.layout)
        self._mlp, self._features = _split_after_features(graph, self.layout, options)
        if self._mlp is not None and not self._split_agrees():
            self._mlp = None  # a feature layer other than tumblebot.sim.control.features': the whole graph
        self._design: tuple[float, ...] | None = None

    @property
    def needs_design(self) -> bool:
        """Whether :meth:`reset` must be given the design (a ``context`` policy)."""
        return self.context.needs_design

    def reset(self, design: Sequence[float] | None = None) -> None:
        """Start an episode or trial on the robot ``design`` ``(x, y, z, l)``, m (default:
        the one given to :meth:`bind_design`); a ``thesis`` policy ignores it."""
        self.context.reset(self._design if design is None else design)

    def bind_design(self, design: Sequence[float]) -> None:
        """The robot every later :meth:`reset` without a design is for (the host's
        ``trial run --design``): checked now, so a bad design fails before any trial."""
        self.context.reset(design)
        self._design = tuple(float(v) for v in design)

    def act_batch(self, inputs: np.ndarray) -> np.ndarray:
        """``(B, N)`` inputs in this policy's layout (N = 9 for ``thesis``) → ``(B, 2)``
        int64 actions. Stateless: for tests and benchmarks; episodes use :meth:`act`."""
        size = len(LAYOUTS[self.layout])
        out = self.session.run(None, {self._input: np.asarray(inputs, dtype=np.float32).reshape(-1, size)})
        return np.asarray(out[0], dtype=np.int64)

    def _split_agrees(self, n: int = 512) -> bool:
        """Whether :func:`features.compute` and the graph's MLP give the whole graph's actions on
        ``n`` fixed inputs (positions and legs' commands spread over their ranges)."""
        rng = np.random.default_rng(0)
        x = rng.uniform(-2.0, 2.0, size=(n, len(LAYOUTS[self.layout]))).astype(np.float32)
        if self.layout != "thesis":
            x[:, features.DESIGN] = rng.uniform(0.05, 0.4, size=(n, 4))
            proposals = x[:, features.PROPOSALS]  # goto's actions, 0/1/2 (none before residual)
            proposals[:] = rng.integers(0, 3, size=proposals.shape)
        fast = self._mlp.run(None, {self._features: features.compute(self.layout, x)})[0]
        return bool(np.array_equal(np.asarray(fast, dtype=np.int64), self.act_batch(x)))

    @property
    def split(self) -> bool:
        """Whether :meth:`act` computes the feature layer itself and runs the graph's MLP alone."""
        return self._mlp is not None

    def act(self, obs: np.ndarray) -> np.ndarray:
        """The action for the thesis observation ``obs`` before the next step: the feature
        layer in plain Python (:mod:`tumblebot.sim.control.features`), then the graph's MLP alone: the
        whole graph's action (checked when the policy loads) for a fraction of
        onnxruntime's per-node cost (:attr:`split`)."""
        x = self.context(obs)
        if self._mlp is None:
            return np.asarray(self.act_batch(x)[0])
        out = self._mlp.run(None, {self._features: features.compute(self.layout, x[None])})
        action: np.ndarray = np.asarray(out[0], dtype=np.int64)[0]
        return action


def _split_after_features(graph: bytes, layout: str, options: Any) -> tuple[Any, str]:
    """The graph after the feature layer, as its own onnxruntime session, and the name of
    its input: the first matrix product with a constant weight takes the features. ``(None,
    "")`` when the graph has no such point of the expected width (then :meth:`OnnxPolicy.act`
    runs the whole graph)."""
    import onnx
    import onnxruntime as ort
    from onnx import numpy_helper, utils

    model = onnx.load_from_string(graph)
    weights = {w.name: w for w in model.graph.initializer}
    for node in model.graph.node:
        if node.op_type in ("Gemm", "MatMul") and len(node.input) > 1 and node.input[1] in weights:
            if len(features.FEATURES[layout]) not in numpy_helper.to_array(weights[node.input[1]]).shape:
                return None, ""
            mlp = utils.Extractor(model).extract_model([node.input[0]], [o.name for o in model.graph.output])
            return ort.InferenceSession(mlp.SerializeToString(), options, providers=["CPUExecutionProvider"]), \
                node.input[0]
    return None, ""
