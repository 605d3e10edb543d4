"""Running batches of episodes for many designs, in a pool that outlives one design.

:func:`tumblebot.sim.evaluation.evaluate.evaluate` starts worker processes for one design; the
optimiser and the report evaluate thousands of designs, so they use an
:class:`EpisodeRunner` instead: its workers keep one environment and one ONNX policy per
task and only change the design between episodes (``reset(options={"design": w})``).

Episode ``i`` of seed ``S`` is always reset with ``episode_seed(S, i)``, for every design,
task and controller: common random numbers, so two designs (or two controllers) are
compared on the same starts, terrains, masses, friction, motor noise and latency, and a
batch can be extended later (episodes ``b..B-1``) without repeating or changing episodes
``0..b-1``.

A runner's *lanes* are what :meth:`EpisodeRunner.run` is asked for: by default one per task
(``{"nav-flat": policy, "incline": policy}``); with ``task=``, several controllers of the
same task side by side under labels of the caller's (``{"policy": path, "goto": Driver.of_gait("goto")}``),
on one pool, so that comparing controllers does not start a pool for each.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np

from tumblebot.sim.control.drivers import Driver, episode_seed
from tumblebot.sim.errors import SimError
from tumblebot.sim.evaluation.pool import WorkerPool
from tumblebot.sim.evaluation.rollout import Actor, make_actor, run_episode
from tumblebot.sim.world.design import Design
from tumblebot.sim.world.physics import PhysicsProfile
from tumblebot.sim.world.tasks import get_task

Job = tuple[str, tuple[float, float, float, float], int, int]  # lane, design, episode index, reset seed
Result = tuple[str, int, float, tuple[float, float, float]]  # lane, episode index, final R, final position
Lane = tuple[str, Driver]  # the task, and what drives it


class _Worker:
    """One process's environments (one per task) and controllers (one per lane), reused
    across designs. Lanes of one task share its environment: every episode is reset from
    its seed, so what ran before it does not matter."""

    def __init__(self, lanes: dict[str, Lane], physics: PhysicsProfile) -> None:
        self.lanes, self.physics = lanes, physics
        self.envs: dict[str, Any] = {}
        self.actors: dict[str, Actor] = {}

    def run(self, job: Job) -> Result:
        lane, w, index, seed = job
        task, controller = self.lanes[lane]
        if task not in self.envs:
            self.envs[task] = self.physics.make_env(task)
        if lane not in self.actors:
            self.actors[lane] = make_actor(controller.kind, controller.name, task)
        out = run_episode(self.envs[task], self.actors[lane], seed,
                          options={"design": Design.from_sequence(w, allow_out_of_bounds=True)})
        return lane, index, out.final_R, out.final_position

    def close(self) -> None:
        for env in self.envs.values():
            env.close()
        self.envs.clear()


def _run_job(worker: _Worker, job: Job) -> Result:
    return worker.run(job)


class EpisodeRunner:
    """Runs episodes on any design; reuse it for many designs, on the package's one
    worker pool (:class:`~tumblebot.sim.evaluation.pool.WorkerPool`). :func:`tumblebot.sim.evaluation.evaluate.evaluate`
    runs on it too.

    Args:
        controllers: lane → what drives it: an ONNX policy path, or a
            :class:`~tumblebot.sim.control.drivers.Driver` (a policy, a gait or ``goto``).
            Without ``task`` the lanes are task names, and every task to be run needs one;
            with it, they are labels of the caller's, every one driving ``task``.
        workers: worker processes (1 runs in this process).
        physics: the physics profile of every episode (default: ``thesis``).
        task: run every controller on this task, side by side (see the module's notes).
    """

    def __init__(self, controllers: Mapping[str, Path | str | Driver], workers: int = 1,
                 physics: PhysicsProfile | None = None, *, task: str | None = None) -> None:
        if workers < 1:
            raise SimError(f"workers={workers} must be at least 1")
        if not controllers:
            raise SimError("an episode runner needs at least one controller")
        self.physics = physics or PhysicsProfile()
        self.task = None if task is None else get_task(task).name
        lanes: dict[str, Lane] = {}
        for key, c in controllers.items():
            name = self.task or get_task(key).name
            spec = c if isinstance(c, Driver) else Driver("onnx", str(c))
            spec.check(name, self.physics)  # fail fast, in this process, with a clear error
            lanes[key if self.task else name] = (name, spec)
        self.lanes = lanes
        self.workers = workers
        self.episodes_run = 0
        self._pool: WorkerPool[_Worker] | None = WorkerPool(_Worker, (self.lanes, self.physics), workers)

    def lane(self, key: str) -> Lane:
        """The task of lane ``key`` and its controller (a task's name may be given in any
        spelling :func:`~tumblebot.sim.world.tasks.get_task` accepts)."""
        return self.lanes[self.lane_key(key)]

    def lane_key(self, key: str) -> str:
        """The key :meth:`run` answers lane ``key`` under (a task's canonical name)."""
        if key in self.lanes:
            return key
        if self.task is None:
            name = get_task(key).name
            if name in self.lanes:
                return name
        raise SimError(f"no controller given for {key!r} (this runner has {', '.join(self.lanes)})")

    def run(self, design: Design, lanes: Iterable[str], start: int, stop: int, seed: int,
            on_result: Callable[[], object] | None = None) -> dict[str, np.ndarray]:
        """Final-state R of episodes ``start..stop-1`` in each of ``lanes`` (task names,
        or the labels given with ``task``), in episode order.

        ``on_result`` is called after every episode, in this process: a safe point, where
        it may raise to stop (the pool is then left to :meth:`close`)."""
        return {t: r for t, (r, _) in self.run_outcomes(design, lanes, start, stop, seed, on_result).items()}

    def run_outcomes(self, design: Design, lanes: Iterable[str], start: int, stop: int, seed: int,
                     on_result: Callable[[], object] | None = None) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Like :meth:`run`, with the final positions too: lane → (R ``(N,)``, positions ``(N, 3)``)."""
        keys = [self.lane_key(k) for k in lanes]
        if not 0 <= start <= stop:
            raise SimError(f"episode range {start}..{stop} is empty or negative")
        jobs: list[Job] = [(k, design.as_tuple(), i, episode_seed(seed, i)) for k in keys for i in range(start, stop)]
        out = {k: (np.full(stop - start, np.nan), np.full((stop - start, 3), np.nan)) for k in keys}
        if self._pool is None:
            raise SimError("the episode runner is closed")
        results = self._pool.imap_unordered(_run_job, jobs, chunksize=max(1, len(jobs) // (4 * self.workers)))
        for key, index, R, position in results:
            out[key][0][index - start] = R
            out[key][1][index - start] = position
            self.episodes_run += 1
            if on_result is not None:
                on_result()
        return out

    def close(self) -> None:
        if self._pool is not None:
            self._pool.close()
            self._pool = None

    def __enter__(self) -> EpisodeRunner:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()


def run_many(runner: EpisodeRunner, designs: Sequence[Design], tasks: Sequence[str], episodes: int,
             seed: int) -> list[dict[str, np.ndarray]]:
    """:meth:`EpisodeRunner.run` over several designs (episodes ``0..episodes-1`` each)."""
    return [runner.run(w, tasks, 0, episodes, seed) for w in designs]
