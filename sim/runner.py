"""Running batches of episodes for many designs, in a pool that outlives one design.

:func:`tumblebot.sim.evaluate.evaluate` starts worker processes for one design; the
optimiser and the report evaluate thousands of designs, so they use an
:class:`EpisodeRunner` instead: its workers keep one environment and one ONNX policy per
task and only change the design between episodes (``reset(options={"design": w})``).

Episode ``i`` of seed ``S`` is always reset with ``episode_seed(S, i)``, for every design
and task: common random numbers, so two designs are compared on the same starts,
terrains, masses, friction, motor noise and latency, and a batch can be extended later
(episodes ``b..B-1``) without repeating or changing episodes ``0..b-1``.
"""

from __future__ import annotations

import multiprocessing as mp
import signal
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np

from tumblebot.sim.design import Design
from tumblebot.sim.errors import SimError
from tumblebot.sim.evaluate import episode_seed
from tumblebot.sim.tasks import get_task

Job = tuple[str, tuple[float, float, float, float], int, int]  # task, design, episode index, reset seed

_state: dict[str, Any] = {}


def _init_worker(policies: dict[str, str], in_process: bool = False) -> None:
    if not in_process:
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C and stops cleanly
    _state.clear()
    _state["policy_paths"] = policies
    _state["envs"] = {}
    _state["policies"] = {}


def _env_and_policy(task: str) -> tuple[Any, Any]:
    envs, policies = _state["envs"], _state["policies"]
    if task not in envs:
        from tumblebot.sim.env import TumblerEnv
        from tumblebot.sim.policy import OnnxPolicy
        from tumblebot.sim.randomization import Randomization

        envs[task] = TumblerEnv(task=task, randomization=Randomization(design=False))
        policies[task] = OnnxPolicy(Path(_state["policy_paths"][task]), task=task)
    return envs[task], policies[task]


def _run_job(job: Job) -> tuple[str, int, float]:
    task, w, index, seed = job
    env, policy = _env_and_policy(task)
    obs, _ = env.reset(seed=seed, options={"design": Design.from_sequence(w, allow_out_of_bounds=True)})
    info: dict[str, Any] = {}
    for _ in range(env.episode_steps):
        obs, _, _, truncated, info = env.step(policy.act(obs))
        if truncated:
            break
    return task, index, float(info["final_R"])


def _close_worker() -> None:
    for env in _state.get("envs", {}).values():
        env.close()
    _state.clear()


class EpisodeRunner:
    """Runs episodes of ONNX policies on any design; reuse it for many designs.

    Args:
        policies: task name → ONNX policy path. Every task to be run needs one.
        workers: worker processes (1 runs in this process).
    """

    def __init__(self, policies: dict[str, Path], workers: int = 1) -> None:
        if workers < 1:
            raise SimError(f"workers={workers} must be at least 1")
        from tumblebot.sim.policy import OnnxPolicy

        for task, path in policies.items():
            OnnxPolicy(path, task=get_task(task).name)  # fail fast, in this process, with a clear error
        self.policies = {get_task(t).name: str(p) for t, p in policies.items()}
        self.workers = workers
        self.episodes_run = 0
        self._pool: Any = None
        if workers > 1:
            self._pool = mp.get_context("forkserver").Pool(workers, initializer=_init_worker,
                                                            initargs=(self.policies,))
        else:
            _init_worker(self.policies, in_process=True)  # this process's Ctrl-C handling is left alone

    def run(self, design: Design, tasks: Iterable[str], start: int, stop: int, seed: int,
            on_result: Callable[[], None] | None = None) -> dict[str, np.ndarray]:
        """Final-state R of episodes ``start..stop-1`` of each task, in episode order.

        ``on_result`` is called after every episode, in this process: a safe point, where
        it may raise to stop (the pool is then left to :meth:`close`)."""
        names = [get_task(t).name for t in tasks]
        missing = [t for t in names if t not in self.policies]
        if missing:
            raise SimError(f"no policy given for task(s) {', '.join(missing)}")
        if not 0 <= start <= stop:
            raise SimError(f"episode range {start}..{stop} is empty or negative")
        jobs: list[Job] = [(t, design.as_tuple(), i, episode_seed(seed, i)) for t in names for i in range(start, stop)]
        out = {t: np.full(stop - start, np.nan) for t in names}
        results: Iterable[tuple[str, int, float]]
        if self._pool is None:
            results = map(_run_job, jobs)
        else:
            results = self._pool.imap_unordered(_run_job, jobs, chunksize=max(1, len(jobs) // (4 * self.workers)))
        for task, index, R in results:
            out[task][index - start] = R
            self.episodes_run += 1
            if on_result is not None:
                on_result()
        return out

    def close(self) -> None:
        if self._pool is not None:
            self._pool.terminate()
            self._pool.join()
            self._pool = None
        else:
            _close_worker()

    def __enter__(self) -> EpisodeRunner:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()


def run_many(runner: EpisodeRunner, designs: Sequence[Design], tasks: Sequence[str], episodes: int,
             seed: int) -> list[dict[str, np.ndarray]]:
    """:meth:`EpisodeRunner.run` over several designs (episodes ``0..episodes-1`` each)."""
    return [runner.run(w, tasks, 0, episodes, seed) for w in designs]
