"""Hand-written alternatives to ``plan``, paired with it on designs drawn afresh.

Each controller drives the same episodes as the baseline (``--baseline``, ``plan`` unless
told; ``tumblebot evaluate``'s seeding and randomisation, the thesis's physics) on
``--designs`` designs drawn uniformly from the bounds with ``--design-seed``, keeping those
whose legs can tumble the body (and, with ``--reach-below`` or ``--reach-above``, whose
reach ``l / r`` lies below or at least at that bound). Per design it prints the baseline's
mean final R and each controller's paired difference with its standard error; then the
means over the designs. Controllers (``--controller``, repeatable; ``--baseline`` takes the
same names):

* ``goto`` or ``plan``: the controllers ``--gait`` names.
* ``SETTING=VALUE;…``: ``plan`` with other :class:`~tumblebot.sim.control.goto.GotoConfig`
  settings (``turn_tolerance=0.5``).
* ``near=C``: ``plan`` that never spins closer to the goal than ``C`` drive-step lengths
  (a spin shifts the body by an amount the observation does not predict).
* ``predict=C``: ``plan``'s estimates, turning and stall rules, but each step it chooses
  between stopping, driving and spinning by predicting the final distance of the best
  plan of each kind over the remaining steps (``k`` spins, then drives in either
  direction), charging ``C`` metres for every planned spin.

    .venv/bin/python reports/policy-headroom/planners.py --task nav-flat --designs 12 \\
        --design-seed 11 --episodes 32 --seed 1 --controller near=1 --controller predict=0.02
    .venv/bin/python reports/policy-headroom/planners.py --reach-above 1.361 --designs 40 \
        --design-seed 29 --episodes 32 --seed 6 --baseline "turn_tolerance=0.3;spin_steps_left=4" \
        --controller "turn_tolerance=0.3;spin_steps_left=5"
"""

from __future__ import annotations

import argparse
import contextlib
import math
import multiprocessing
import sys
from dataclasses import fields, replace
from typing import Any

import numpy as np

from tumblebot.cliargs import reach_bound
from tumblebot.sim.control.goto import (
    FORWARD,
    MIN_STEP_LENGTH,
    NAVIGATION_TASKS,
    NAVIGATORS,
    STALLED_RATE,
    STOP,
    Action,
    GotoConfig,
    GotoController,
)
from tumblebot.sim.observation import POSITION
from tumblebot.sim.world.design import Design, tumbling_designs

_ENV: dict[str, Any] = {}


class NoSpinNearGoal(GotoController):
    """``plan`` that drives or stops, never spins, within ``near`` step lengths of the goal."""

    def __init__(self, config: GotoConfig, near: float) -> None:
        self.near = near
        super().__init__(config)

    def act(self, obs: np.ndarray, step: int) -> Action:
        position = np.asarray(obs[POSITION][:2], dtype=float)
        if float(np.hypot(*position)) >= self.near * max(self.step_length, MIN_STEP_LENGTH):
            return super().act(obs, step)
        config, self.config = self.config, replace(self.config, spin_steps_left=self.config.episode_steps)
        try:  # no spin while every step is "too late to spin"
            return super().act(obs, step)
        finally:
            self.config = config


class PredictingPlanner(GotoController):
    """Stop, drive or spin: whichever kind of plan over the remaining steps is predicted to
    end closest to the goal (spins charged ``spin_cost`` metres each)."""

    def __init__(self, config: GotoConfig, spin_cost: float) -> None:
        self.spin_cost = spin_cost
        super().__init__(config)

    @staticmethod
    def _closest(position: np.ndarray, theta: float, length: float, steps: int) -> tuple[float, int]:
        """The smallest distance to the goal after 0..``steps`` drives toward ``theta``."""
        u = np.array([math.cos(theta), math.sin(theta)])
        ends = [float(np.hypot(*(position + n * length * u))) for n in range(steps + 1)]
        n = int(np.argmin(ends))
        return ends[n], n

    def act(self, obs: np.ndarray, step: int) -> Action:
        cfg = self.config
        position, psi = self.observe(obs)
        distance = float(np.hypot(*position))
        steps_left = cfg.episode_steps - step
        length = max(self.step_length, MIN_STEP_LENGTH)
        active = steps_left - 1  # the last step stops
        action = STOP
        if distance >= cfg.stop_fraction * length and active >= 1:
            error, drive = self.drive_toward_goal(position, psi)
            offset = -math.pi / 2 if drive == FORWARD else math.pi / 2
            end, drives = self._closest(position, psi + offset, length, active)
            options: list[tuple[float, Action]] = [(distance, STOP)]
            if drives:
                options.append((end + cfg.margin, drive))
            spin = self._turn(error, drive, 1.0)
            rate = self.spin_rate.get(spin, 0.0)
            if steps_left > cfg.spin_steps_left and abs(rate) > STALLED_RATE:
                for k in range(1, active):
                    after = min(self._closest(position, psi + k * rate + sign * offset, length, active - k)[0]
                                for sign in (1, -1))
                    options.append((after + cfg.margin + self.spin_cost * k, spin))
            action = min(options, key=lambda o: o[0])[1]
        self._action = action
        return action


def controller(name: str) -> GotoController:
    """The controller a ``--controller`` value names (see the module's docstring)."""
    plan = NAVIGATORS["plan"]
    if name in NAVIGATORS:
        return GotoController(NAVIGATORS[name])
    key, _, value = name.partition("=")
    if key == "near":
        return NoSpinNearGoal(plan, float(value))
    if key == "predict":
        return PredictingPlanner(plan, float(value))
    known = {f.name: f.type for f in fields(GotoConfig)}
    settings: dict[str, Any] = {}
    for item in name.split(";"):
        key, _, value = item.partition("=")
        if key not in known or not value:
            raise ValueError(f"{item!r}: expected goto, near=C, predict=C or SETTING=VALUE;… "
                             f"with SETTING one of {', '.join(known)}")
        settings[key] = int(value) if known[key] in (int, "int") else float(value)
    return GotoController(replace(plan, **settings))


def _episode(job: tuple[str, tuple[float, ...], int, int, list[str]]) -> list[float]:
    """Final R of one episode under each named controller, in order (the baseline first)."""
    from tumblebot.sim.control.drivers import episode_seed
    from tumblebot.sim.evaluation.rollout import GotoActor, run_episode
    from tumblebot.sim.world.physics import THESIS

    task, design, seed, index, names = job
    if task not in _ENV:  # one environment per worker and task
        _ENV[task] = THESIS.make_env(task)
    options = {"design": Design.from_sequence(design, allow_out_of_bounds=True)}
    return [run_episode(_ENV[task], GotoActor(controller(name)), episode_seed(seed, index), options).final_R
            for name in names]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--task", default="nav-flat", choices=NAVIGATION_TASKS)
    parser.add_argument("--controller", action="append", required=True,
                        help="a controller to pair with the baseline (repeatable)")
    parser.add_argument("--baseline", default="plan", help="the controller each is paired with (plan)")
    parser.add_argument("--designs", type=int, default=12)
    parser.add_argument("--design-seed", type=int, default=11)
    parser.add_argument("--reach-below", type=reach_bound, metavar="L/R",
                        help="keep only designs whose legs reach less than this many pivot radii (l/r)")
    parser.add_argument("--reach-above", type=reach_bound, metavar="L/R",
                        help="keep only designs whose legs reach at least this many pivot radii (l/r)")
    parser.add_argument("--episodes", type=int, default=32)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--workers", type=int, default=2, help="worker processes (2; 1 runs in this process)")
    args = parser.parse_args(argv)
    try:
        for name in [args.baseline, *args.controller]:
            controller(name)
    except (ValueError, TypeError) as exc:
        print(f"planners: {exc}", file=sys.stderr)
        return 2
    if args.designs < 1 or args.episodes < 2 or args.workers < 1:
        print("planners: need --designs ≥ 1, --episodes ≥ 2 and --workers ≥ 1", file=sys.stderr)
        return 2
    if args.reach_below is not None and args.reach_above is not None and args.reach_above >= args.reach_below:
        print("planners: --reach-above must be below --reach-below", file=sys.stderr)
        return 2
    try:
        designs = tumbling_designs(args.designs, args.design_seed, args.reach_below, args.reach_above)
    except ValueError as exc:
        print(f"planners: {exc}", file=sys.stderr)
        return 2
    names = args.controller
    base = "plan" if args.baseline == "plan" else "base"
    print(f"{args.task}, {args.designs} designs drawn with seed {args.design_seed}"
          + (f" with l/r below {args.reach_below}" if args.reach_below is not None else "")
          + (f" with l/r at least {args.reach_above}" if args.reach_above is not None else "")
          + f", {args.episodes} paired episodes each (seed {args.seed}): "
          + ("" if base == "plan" else f"the baseline {args.baseline}: ")
          + f"{base}'s mean final R and each controller's difference (± s.e.)")
    print(f"{'design (x, y, z, l)':30s} {'l/r':>4s} {base:>6s}  " + "  ".join(f"{n:>18s}" for n in names))
    rows = []
    with contextlib.ExitStack() as stack:  # --workers 1 runs in this process
        pool = (stack.enter_context(multiprocessing.get_context("forkserver").Pool(args.workers))
                if args.workers > 1 else None)
        for design in designs:
            jobs = [(args.task, design.as_tuple(), args.seed, i, [args.baseline, *names])
                    for i in range(args.episodes)]
            R = np.array(pool.map(_episode, jobs, chunksize=4) if pool is not None else [_episode(j) for j in jobs])
            diff = R[:, 1:] - R[:, :1]
            se = diff.std(axis=0, ddof=1) / math.sqrt(args.episodes)
            rows.append(R.mean(axis=0))
            text = "(" + ", ".join(f"{v:.3f}" for v in design.as_tuple()) + ")"
            print(f"{text:30s} {design.reach:4.2f} {R[:, 0].mean():6.3f}  "
                  + "  ".join(f"{d:>+11.3f} ±{s:.3f}" for d, s in zip(diff.mean(axis=0), se, strict=True)),
                  flush=True)
    means = np.mean(rows, axis=0)
    print(f"{'mean over the designs':35s} {means[0]:6.3f}  "
          + "  ".join(f"{m - means[0]:>+18.3f}" for m in means[1:]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
