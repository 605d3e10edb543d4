"""What a navigation policy loses or gains by doing something else at one step: a local
optimality test, and the variance a self-critical policy gradient would face.

Each episode (the training randomisation: designs drawn over those that can tumble, goals
and motor noise from the episode's seed) is driven by the policy's own action at every
step, and then again from a snapshot of ``--deviations`` of its steps, chosen at random,
with another action at that step and the policy's own after it. The two episodes share
everything but that one action: the same body, goal, and motor noise and latency to come
(:meth:`TumblerEnv.snapshot`). Their difference in final R is the advantage of the other
action over the policy's at that state, ``Q(s, a) - V(s)`` for the policy itself, measured
with common random numbers.

A policy that some change of one action improves on average has a positive mean advantage
in that class of states; the spread of the advantages is the noise a policy gradient with
a per-episode baseline from the deterministic policy (self-critical) must average away.
The other action is drawn uniformly from the eight the policy did not take.

    .venv/bin/python reports/policy-headroom/deviations.py [--policy policies/nav-flat.onnx] \\
        [--episodes 400] [--deviations 4] [--seed 3] [--workers 2] [--json out.json]
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from tumblebot.sim.control.features import DESIGN
from tumblebot.sim.control.policy import OnnxPolicy, PolicyError
from tumblebot.sim.evaluation import rollout
from tumblebot.sim.evaluation.pool import WorkerPool
from tumblebot.sim.evaluation.rollout import PolicyActor, run_episode
from tumblebot.sim.world.physics import THESIS
from tumblebot.training.lookahead import ALL_ACTIONS

DEFAULT_POLICY = Path("policies/nav-flat.onnx")
#: the step ranges the advantages are summarised over
STEP_RANGES = ((0, 1), (1, 3), (3, 7), (7, 14), (14, 18), (18, 20))
NAMES = {0: "R", 1: "S", 2: "F"}  #: a leg's action: full reverse, stop, full forward


def action_name(index: int) -> str:
    """The joint action ``ALL_ACTIONS[index]`` as two letters (right leg, left leg)."""
    right, left = ALL_ACTIONS[index]
    return NAMES[right] + NAMES[left]


@dataclass
class _Worker:
    env: Any
    policy: OnnxPolicy


def _worker(policy: str, task: str) -> _Worker:
    from tumblebot.sim.world.env import TumblerEnv
    from tumblebot.sim.world.randomization import Randomization

    env = TumblerEnv(task=task, randomization=THESIS.randomization(Randomization(tumbling_designs_only=True)),
                     **THESIS.env_kwargs())
    return _Worker(env, OnnxPolicy(Path(policy), task=task))


@dataclass(frozen=True)
class Branch:
    """A point of an episode to deviate from: the simulation before step ``step``, the
    policy's memory before it saw ``obs``, and the action it took there."""

    step: int
    snapshot: Any
    context: Any
    obs: np.ndarray
    own: int  #: index in :data:`ALL_ACTIONS`
    inputs: np.ndarray  #: the policy's input there (its layout)


class _Recorder(PolicyActor):
    """The policy, leaving a :class:`Branch` before each step in ``branch_at``."""

    def __init__(self, env: Any, policy: OnnxPolicy, branch_at: set[int]) -> None:
        super().__init__(policy)
        self.env, self.branch_at = env, branch_at
        self.branches: list[Branch] = []

    def act(self, obs: np.ndarray, step: int) -> np.ndarray:
        context = copy.deepcopy(self.policy.context) if step in self.branch_at else None  # the memory before it
        action = self.policy.act(obs)
        if context is not None:
            own = ALL_ACTIONS.index((int(action[0]), int(action[1])))
            inputs = copy.deepcopy(context)(obs)
            self.branches.append(Branch(step, self.env.snapshot(), context, obs, own, inputs))
        return action


def drive(worker: _Worker, seed: int, branch_at: set[int]) -> tuple[float, list[Branch]]:
    """The policy's own episode of ``seed``: its final R, and a :class:`Branch` before
    every step in ``branch_at`` (release their snapshots with :func:`deviate`)."""
    recorder = _Recorder(worker.env, worker.policy, branch_at)
    return run_episode(worker.env, recorder, seed).final_R, recorder.branches


def deviate(worker: _Worker, branch: Branch, action: int) -> float:
    """The final R of the episode from ``branch`` with ``action`` (index in
    :data:`ALL_ACTIONS`) at its step and the policy's own actions after; frees the branch's
    snapshot."""
    policy = worker.policy
    try:
        policy.context = copy.deepcopy(branch.context)
        policy.context(branch.obs)  # the memory sees the state as in the episode; the action differs
        info = rollout.branch(worker.env, branch.snapshot, ALL_ACTIONS[action], PolicyActor(policy), branch.step)
    finally:
        worker.env.release(branch.snapshot)
    return float(info["final_R"])


Row = tuple[int, int, int, float]  #: a deviation: step, own action, other action, advantage


def _episode(worker: _Worker, job: tuple[int, int]) -> tuple[float, list[Row], list[np.ndarray]]:
    """One episode of ``seed``: its final R and, for each deviation, its :data:`Row` and
    the policy's input where it deviated."""
    seed, deviations = job
    rng = np.random.default_rng([seed, 1])
    steps = worker.env.episode_steps
    final, branches = drive(worker, seed, set(rng.choice(steps, size=min(deviations, steps), replace=False).tolist()))
    rows = []
    for branch in branches:
        other = int(rng.choice([i for i in range(len(ALL_ACTIONS)) if i != branch.own]))
        rows.append((branch.step, branch.own, other, deviate(worker, branch, other) - final))
    return final, rows, [branch.inputs for branch in branches]


def _mean_se(values: np.ndarray) -> tuple[float, float]:
    return float(values.mean()), float(values.std(ddof=1) / np.sqrt(len(values))) if len(values) > 1 else float("nan")


def summarise(rows: np.ndarray) -> dict[str, Any]:
    """Mean advantages (± standard error) overall, by step range, by the policy's action,
    and by (policy's action, other action) where a class has 30 deviations or more."""
    step, own, other, advantage = rows[:, 0].astype(int), rows[:, 1].astype(int), rows[:, 2].astype(int), rows[:, 3]
    out: dict[str, Any] = {"deviations": len(rows), "overall": _mean_se(advantage),
                           "positive_share": float(np.mean(advantage > 0)), "sd": float(advantage.std(ddof=1)),
                           "by_step": {}, "by_own_action": {}, "by_pair": {}}
    for lo, hi in STEP_RANGES:
        mask = (step >= lo) & (step < hi)
        if mask.sum() > 1:
            out["by_step"][f"{lo}-{hi - 1}"] = (int(mask.sum()), *_mean_se(advantage[mask]))
    for a in range(len(ALL_ACTIONS)):
        mask = own == a
        if mask.sum() > 1:
            out["by_own_action"][action_name(a)] = (int(mask.sum()), *_mean_se(advantage[mask]))
        for b in range(len(ALL_ACTIONS)):
            pair = mask & (other == b)
            if pair.sum() >= 30 and advantage[pair].std() > 0:
                out["by_pair"][f"{action_name(a)}->{action_name(b)}"] = (int(pair.sum()), *_mean_se(advantage[pair]))
    return out


def _cell(rows: np.ndarray) -> np.ndarray:
    """Each deviation's class: (step range, own action, other action) as one integer."""
    ranges = np.searchsorted([hi for _, hi in STEP_RANGES], rows[:, 0].astype(int), side="right")
    return np.asarray((ranges * 9 + rows[:, 1].astype(int)) * 9 + rows[:, 2].astype(int))


def cross_fit(rows: np.ndarray, halves: np.ndarray, least: int = 10, t: float = 2.0) -> dict[str, Any]:
    """Would a rule "take the other action in these classes" help? The classes (step
    range, own action, other action) whose mean advantage on one half of the episodes
    (``halves`` 0 or 1) is positive by ``t`` standard errors (``least`` deviations or
    more), scored on the other half; both ways round, pooled. A rule that only fits noise
    scores at or below zero there."""
    cells, advantage = _cell(rows), rows[:, 3]
    held_out: list[np.ndarray] = []
    chosen = 0
    for half in (0, 1):
        fit, test = halves == half, halves != half
        good = []
        for c in np.unique(cells[fit]):
            a = advantage[fit][cells[fit] == c]
            if len(a) >= least and a.mean() > t * a.std(ddof=1) / np.sqrt(len(a)):
                good.append(c)
        chosen += len(good)
        held_out.append(advantage[test & np.isin(cells, good)])
    pooled = np.concatenate(held_out)
    return {"classes_chosen": chosen, "held_out_deviations": len(pooled),
            "held_out": _mean_se(pooled) if len(pooled) > 1 else (float("nan"), float("nan"))}


def episode_numbers(inputs: np.ndarray) -> np.ndarray:
    """Each deviation's episode, numbered 0, 1, … in sorted order of the designs: every
    episode has a body of its own (whatever order the workers finished them in)."""
    _, episode = np.unique(np.round(inputs[:, DESIGN], 9), axis=0, return_inverse=True)
    return np.asarray(episode.reshape(-1))


def episode_halves(inputs: np.ndarray) -> np.ndarray:
    """Which half (0 or 1) each deviation's episode falls in: its episodes taken alternately."""
    return episode_numbers(inputs) % 2


def report(summary: dict[str, Any], episodes: int, finals: np.ndarray | None, policy: Path) -> str:
    """The summary as text (``finals``: the episodes' own final R, where known)."""
    mean, se = summary["overall"]
    own = "" if finals is None or not len(finals) else f" (mean final R {finals.mean():.3f})"
    lines = [f"{policy}: {episodes} episodes{own}, {summary['deviations']} one-step deviations",
             f"mean advantage of another action {mean:+.4f} ± {se:.4f}; sd {summary['sd']:.3f}; "
             f"better than the policy's own in {summary['positive_share']:.0%}",
             "", "steps    deviations  mean advantage ± se"]
    lines += [f"{name:8s} {n:10d}  {m:+.4f} ± {s:.4f}" for name, (n, m, s) in summary["by_step"].items()]
    lines += ["", "own action  deviations  mean advantage ± se"]
    lines += [f"{name:11s} {n:10d}  {m:+.4f} ± {s:.4f}" for name, (n, m, s) in summary["by_own_action"].items()]
    best = sorted(summary["by_pair"].items(), key=lambda item: -item[1][1] / item[1][2])[:5]
    lines += ["", "the five (own -> other) classes most in the other's favour (30 deviations or more)",
              "class       deviations  mean advantage ± se   t"]
    lines += [f"{name:11s} {n:10d}  {m:+.4f} ± {s:.4f}  {m / s:+.1f}" for name, (n, m, s) in best]
    if "cross_fit" in summary:
        fitted = summary["cross_fit"]
        m, s = fitted["held_out"]
        lines += ["", f"taking the other action in the {fitted['classes_chosen']} (step range, own, other) classes "
                  "that gained on one half of the episodes (t > 2),",
                  f"scored on the other half (both ways): {m:+.4f} ± {s:.4f} over "
                  f"{fitted['held_out_deviations']} deviations"]
    return "\n".join(lines)


def collect(policy: Path, task: str, seed: int, episodes: int, deviations: int, workers: int
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Run the episodes: the deviations' rows (step, own, other, advantage), the policy's
    inputs where they deviated, and the episodes' own final R."""
    jobs = [(seed * 1_000_000 + i, deviations) for i in range(episodes)]
    finals: list[float] = []
    rows: list[Row] = []
    inputs: list[np.ndarray] = []
    with WorkerPool(_worker, (str(policy), task), workers) as pool:
        for final, episode_rows, episode_inputs in tqdm(pool.imap_unordered(_episode, jobs), total=len(jobs),
                                                        unit="episode"):
            finals.append(final)
            rows.extend(episode_rows)
            inputs.extend(episode_inputs)
    return np.array(rows, dtype=float), np.array(inputs, dtype=np.float32), np.array(finals)


FIELDS = ("inputs", "step", "own", "other", "advantage")  #: what a --save file holds (and ``finals``)


def load(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """What :func:`collect` returned, from a file ``--save`` wrote; a ValueError naming
    what is wrong with any other file."""
    try:
        data = np.load(path, allow_pickle=False)
        if not hasattr(data, "files") or not set(FIELDS) <= set(data.files):
            raise ValueError(f"it holds no deviations (an .npz with {', '.join(FIELDS)})")
        inputs = np.asarray(data["inputs"], dtype=np.float32)
        rows = np.column_stack([data[name] for name in FIELDS[1:]]).astype(float)
        finals = np.asarray(data["finals"], dtype=float) if "finals" in data.files else np.zeros(0)
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path} is not a file deviations.py --save wrote: {exc}") from None
    if inputs.ndim != 2 or inputs.shape[1] <= DESIGN.stop or len(inputs) != len(rows) or not len(rows):
        raise ValueError(f"{path} is not a file deviations.py --save wrote: its inputs and rows do not match")
    return rows, inputs, finals if len(finals) else None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--policy", type=Path, default=DEFAULT_POLICY,
                        help=f"an ONNX navigation policy (default {DEFAULT_POLICY})")
    parser.add_argument("--task", default="nav-flat", choices=("nav-flat", "nav-terrain"))
    parser.add_argument("--episodes", type=int, default=400, help="episodes (default 400)")
    parser.add_argument("--deviations", type=int, default=4, help="deviations per episode (default 4)")
    parser.add_argument("--seed", type=int, default=3, help="episodes are seeds seed*1e6 + i (default 3)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--json", type=Path, help="also write the summary here")
    parser.add_argument("--from", dest="source", type=Path,
                        help="summarise the deviations a --save wrote instead of running episodes")
    parser.add_argument("--save", type=Path, help="also write every deviation here (.npz: the policy's input, "
                        "step, own and other action, advantage)")
    args = parser.parse_args(argv)
    for name in ("episodes", "deviations", "workers"):
        if getattr(args, name) < 1:
            parser.error(f"--{name} must be at least 1")
    if args.source and not args.source.is_file():
        print(f"deviations: {args.source} does not exist", file=sys.stderr)
        return 2
    try:
        OnnxPolicy(args.policy, task=args.task)
    except PolicyError as exc:
        print(f"deviations: {exc}", file=sys.stderr)
        return 2
    if args.source:
        try:
            rows_table, inputs, finals = load(args.source)
        except ValueError as exc:
            print(f"deviations: {exc}", file=sys.stderr)
            return 2
    else:
        rows_table, inputs, finals = collect(args.policy, args.task, args.seed, args.episodes, args.deviations,
                                             args.workers)
    summary = summarise(rows_table)
    numbers = episode_numbers(inputs)
    summary["cross_fit"] = cross_fit(rows_table, numbers % 2)
    episodes = int(numbers.max()) + 1
    print(report(summary, episodes, finals, args.policy))
    if args.save:
        np.savez_compressed(args.save, inputs=inputs.astype(np.float32), step=rows_table[:, 0].astype(int),
                            own=rows_table[:, 1].astype(int), other=rows_table[:, 2].astype(int),
                            advantage=rows_table[:, 3], finals=finals if finals is not None else np.zeros(0))
    if args.json:
        args.json.write_text(json.dumps({"policy": str(args.policy), "task": args.task, "episodes": episodes,
                                         "seed": args.seed, **summary}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
