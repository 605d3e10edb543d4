"""A self-critical policy gradient on one-step deviations: does the navigation student
improve when every deviation is scored against its own deterministic episode?

PPO from the student compares a stochastic episode's return with a value head's estimate,
and the return's spread across bodies and goals (about 0.4) drowns differences of 0.01.
Here the baseline of each deviation is the student's own deterministic episode on the same
seed (the same body, goal and motor noise): each iteration drives ``--groups`` episodes
of seeds not used before, deviates at ``--deviations`` of their steps from a snapshot
(:mod:`deviations`: another action at that step, the student's own after it), and takes
the advantage ``A = R(deviation) - R(own)``. The other action is drawn from the student's
action distribution at ``--temperature`` among the eight it did not take, mixed half and
half with a uniform draw (``q``). One pass of Adam over the last three iterations'
deviations then maximises the importance-weighted surrogate ``p_T(a | x) A / q(a)``, whose
gradient is the policy gradient of the student at temperature ``T`` with the deterministic
student as baseline (its own action has ``A = 0``). Every ``--validate-every`` iterations
the deterministic student drives ``--validation`` fixed episodes paired with the start.

    .venv/bin/python reports/policy-headroom/self_critical.py \\
        --run training/checkpoints/tri-nav-flat --out runs/self-critical [--iterations 30]
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from tumblebot.sim.evaluation.pool import WorkerPool
from tumblebot.sim.evaluation.rollout import branch
from tumblebot.training.config import TrainConfig
from tumblebot.training.imitation import joint_log_probs
from tumblebot.training.lookahead import ALL_ACTIONS

TRAINING_SEEDS = 10_000_000  #: iteration i's groups are episodes TRAINING_SEEDS + i·groups + j
VALIDATION_SEEDS = 5_000_000  #: the validation episodes, the same at every check


@dataclass
class _Worker:
    env: Any
    policy: Any  #: the SB3 actor-critic, its weights refreshed from the trainer's file
    version: int = -2


def _worker(run: str) -> _Worker:
    from stable_baselines3 import PPO

    from tumblebot.training.ppo import make_env

    config = TrainConfig.load(Path(run) / "config.json")
    env = make_env(config.task, config.reward_weights(), config.randomization(), config.profile(), config.observation)
    policy = PPO.load(Path(run) / "latest.zip", device="cpu").policy
    policy.set_training_mode(False)
    return _Worker(env, policy)


def joint_logits(policy: Any, x: torch.Tensor) -> torch.Tensor:
    """``(B, 9)`` log-probabilities of the joint actions in :data:`ALL_ACTIONS` order."""
    return joint_log_probs(policy.get_distribution(x))


def _own(policy: Any, obs: np.ndarray) -> tuple[int, np.ndarray]:
    with torch.no_grad():
        logits = joint_logits(policy, torch.as_tensor(obs[None], dtype=torch.float32))[0].numpy()
    return int(np.argmax(logits)), logits


class _Own:
    """The student's most likely action (the deterministic policy)."""

    def __init__(self, policy: Any) -> None:
        self.policy = policy

    def reset(self, seed: int, design: tuple[float, float, float, float]) -> None:
        pass

    def act(self, obs: np.ndarray, step: int) -> np.ndarray:
        return np.array(ALL_ACTIONS[_own(self.policy, obs)[0]])


Sample = tuple[np.ndarray, int, float, float, int]  #: input, other action, q(other), advantage, step


def group(worker: _Worker, job: tuple[int, int, str, int, float]) -> tuple[int, float, list[Sample]]:
    """Episode ``seed`` driven by the student of ``weights`` (file of version ``version``)
    and ``deviations`` one-step deviations from it: (seed, own final R, samples)."""
    seed, version, weights, deviations, temperature = job
    if version != worker.version:
        worker.policy.load_state_dict(torch.load(weights))
        worker.version = version
    env, policy = worker.env, worker.policy
    rng = np.random.default_rng([seed, 7])
    steps = env.unwrapped.episode_steps
    chosen = set(rng.choice(steps, size=min(deviations, steps), replace=False).tolist())
    obs, _ = env.reset(seed=seed)
    saved: dict[int, tuple[Any, np.ndarray, int, np.ndarray]] = {}
    info: dict[str, Any] = {}
    for k in range(steps):
        own, logits = _own(policy, obs)
        if k in chosen:
            saved[k] = (env.snapshot(), obs, own, logits)  # the simulation and the input's memory
        obs, _, terminated, truncated, info = env.step(np.array(ALL_ACTIONS[own]))
        if terminated or truncated:
            break
    final = float(info["final_R"])
    samples: list[Sample] = []
    for k, (snap, before, own, logits) in sorted(saved.items()):
        p = np.exp((logits - logits.max()) / temperature)
        others = np.array([i for i in range(len(ALL_ACTIONS)) if i != own])
        q = 0.5 * p[others] / p[others].sum() + 0.5 / len(others)
        pick = int(rng.choice(len(others), p=q / q.sum()))
        result = float(branch(env, snap, ALL_ACTIONS[int(others[pick])], _Own(policy), k)["final_R"])
        env.release(snap)
        samples.append((before, int(others[pick]), float(q[pick]), result - final, k))
    return seed, final, samples


def surrogate(policy: Any, x: torch.Tensor, other: torch.Tensor, q: torch.Tensor, advantage: torch.Tensor,
              temperature: float) -> torch.Tensor:
    """Minus the importance-weighted surrogate ``mean(p_T(other | x) · A / q)``."""
    p = torch.softmax(joint_logits(policy, x) / temperature, dim=1).gather(1, other[:, None])[:, 0]
    return -(p / q * advantage).mean()


def update(policy: Any, optimiser: torch.optim.Optimizer, data: list[Sample], temperature: float, seed: int) -> None:
    """One pass of minibatches of 128 over ``data``, in an order drawn from ``seed``."""
    x = torch.as_tensor(np.array([s[0] for s in data]), dtype=torch.float32)
    other = torch.as_tensor([s[1] for s in data])
    q = torch.as_tensor([s[2] for s in data], dtype=torch.float32)
    advantage = torch.as_tensor([s[3] for s in data], dtype=torch.float32)
    policy.set_training_mode(True)
    order = np.random.default_rng(seed).permutation(len(data))
    for b in range(0, len(order), 128):
        idx = torch.as_tensor(order[b:b + 128])
        loss = surrogate(policy, x[idx], other[idx], q[idx], advantage[idx], temperature)
        optimiser.zero_grad()
        loss.backward()  # type: ignore[no-untyped-call]
        torch.nn.utils.clip_grad_norm_(policy.parameters(), 1.0)
        optimiser.step()
    policy.set_training_mode(False)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--run", type=Path, required=True, help="a training run folder (config.json, latest.zip)")
    parser.add_argument("--out", type=Path, required=True, help="where the log and the weights go")
    parser.add_argument("--init", type=Path, help="start from these weights (a state dict this script wrote)")
    parser.add_argument("--iterations", type=int, default=30)
    parser.add_argument("--groups", type=int, default=160, help="episodes per iteration (default 160)")
    parser.add_argument("--deviations", type=int, default=4, help="deviations per episode (default 4)")
    parser.add_argument("--temperature", type=float, default=4.0)
    parser.add_argument("--learning-rate", type=float, default=3e-5)
    parser.add_argument("--validation", type=int, default=240, help="validation episodes (default 240)")
    parser.add_argument("--validate-every", type=int, default=5)
    parser.add_argument("--seed-offset", type=int, default=0, help="added to the training episodes' seeds")
    parser.add_argument("--workers", type=int, default=2)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    if not (args.run / "latest.zip").is_file() or not (args.run / "config.json").is_file():
        print(f"self_critical: {args.run} is not a training run (config.json, latest.zip)", file=sys.stderr)
        return 2
    for name in ("iterations", "groups", "deviations", "validation", "validate_every", "workers"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be at least 1")
    from stable_baselines3 import PPO

    args.out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(1)
    policy = PPO.load(args.run / "latest.zip", device="cpu").policy
    if args.init:
        policy.load_state_dict(torch.load(args.init))
    optimiser = torch.optim.Adam(policy.parameters(), lr=args.learning_rate)
    log = (args.out / "log.txt").open("a")

    def say(line: str) -> None:
        print(line, flush=True)
        log.write(line + "\n")
        log.flush()

    def save(version: int) -> str:
        path = args.out / f"weights-{version}.pt"
        torch.save(policy.state_dict(), path)
        return str(path)

    with WorkerPool(_worker, (str(args.run),), args.workers) as pool:
        def validate(version: int) -> np.ndarray:
            path = save(version)
            jobs = [(VALIDATION_SEEDS + i, version, path, 0, args.temperature) for i in range(args.validation)]
            return np.array([final for _, final, _ in sorted(pool.map(group, jobs))])

        start = validate(-1)
        say(f"start: validation mean final R {start.mean():.4f}")
        recent: list[list[Sample]] = []
        for it in range(args.iterations):
            path = save(it)
            first = TRAINING_SEEDS + args.seed_offset + it * args.groups
            jobs = [(first + j, it, path, args.deviations, args.temperature) for j in range(args.groups)]
            results = pool.map(group, jobs)
            samples = [s for _, _, episode in results for s in episode]
            recent = [*recent[-2:], samples]
            update(policy, optimiser, [s for batch in recent for s in batch], args.temperature, it)
            a = np.array([s[3] for s in samples])
            say(f"iteration {it}: own final R {np.mean([f for _, f, _ in results]):.4f}, "
                f"{len(a)} deviations, mean advantage {a.mean():+.4f} ± {a.std(ddof=1) / np.sqrt(len(a)):.4f}")
            if (it + 1) % args.validate_every == 0 or it + 1 == args.iterations:
                d = validate(it + 1) - start
                say(f"validation after {it + 1}: paired difference {d.mean():+.4f} ± "
                    f"{d.std(ddof=1) / np.sqrt(len(d)):.4f}, episodes changed {np.mean(np.abs(d) > 0):.0%}")
    log.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
