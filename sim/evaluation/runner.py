"""Running batches of episodes for many designs, in a pool that outlives one design.

:func:`tumblebot.sim.evaluation.evaluate.evaluate` starts worker processes for one design; the
optimiser and the report evaluate thousands of designs, so they use an
:class:`EpisodeRunner` instead: its workers keep one environment and one ONNX policy per
task and only change the design between episodes (``reset(options={"design": w})``).

Episode ``i`` of seed ``S`` is always reset with ``episode_seed(S, i)``, for every design
and task: common random numbers, so two designs are compared on the same starts,
terrains, masses, friction, motor noise and latency, and a batch can be extended later
(episodes ``b..B-1``) without repeating or changing episodes ``0..b-1``.
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

Job = tuple[str, tuple[float, float, float, float], int, int]  # task, design, episode index, reset seed
Result = tuple[str, int, float, tuple[float, float, float]]  # task, episode index, final R, final position

class _Worker:
    """One process's environments and controllers, one per task, reused across designs."""

    def __init__(self, controllers: dict[str, Driver], physics: PhysicsProfile) -> None:
        self.controllers, self.physics = controllers, physics
        self.envs: dict[str, Any] = {}
        self.actors: dict[str, Actor] = {}

    def run(self, job: Job) -> Result:
        task, w, index, seed = job
        if task not in self.envs:
            self.envs[task] = self.physics.make_env(task)
            controller = self.controllers[task]
            self.actors[task] = make_actor(controller.kind, controller.name, task)
        out = run_episode(self.envs[task], self.actors[task], seed,
                          options={"design": Design.from_sequence(w, allow_out_of_bounds=True)})
        return task, index, out.final_R, out.final_position

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
        controllers: task name → what drives it: an ONNX policy path, or a
            :class:`~tumblebot.sim.control.drivers.Driver` (a policy, a gait or ``goto``).
            Every task to be run needs one.
        workers: worker processes (1 runs in this process).
        physics: the physics profile of every episode (default: ``thesis``).
    """

    def __init__(self, controllers: Mapping[str, Path | str | Driver], workers: int = 1,
                 physics: PhysicsProfile | None = None) -> None:
        if workers < 1:
            raise SimError(f"workers={workers} must be at least 1")
        self.physics = physics or PhysicsProfile()
        specs: dict[str, Driver] = {}
        for task, c in controllers.items():
            name = get_task(task).name
            spec = c if isinstance(c, Driver) else Driver("onnx", str(c))
            spec.check(name, self.physics)  # fail fast, in this process, with a clear error
            specs[name] = spec
        self.controllers = specs
        self.workers = workers
        self.episodes_run = 0
        self._pool: WorkerPool[_Worker] | None = WorkerPool(_Worker, (self.controllers, self.physics), workers)

    def run(self, design: Design, tasks: Iterable[str], start: int, stop: int, seed: int,
            on_result: Callable[[], object] | None = None) -> dict[str, np.ndarray]:
        """Final-state R of episodes ``start..stop-1`` of each task, in episode order.

        ``on_result`` is called after every episode, in this process: a safe point, where
        it may raise to stop (the pool is then left to :meth:`close`)."""
        return {t: r for t, (r, _) in self.run_outcomes(design, tasks, start, stop, seed, on_result).items()}

    def run_outcomes(self, design: Design, tasks: Iterable[str], start: int, stop: int, seed: int,
                     on_result: Callable[[], object] | None = None) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Like :meth:`run`, with the final positions too: task → (R ``(N,)``, positions ``(N, 3)``)."""
        names = [get_task(t).name for t in tasks]
        missing = [t for t in names if t not in self.controllers]
        if missing:
            raise SimError(f"no controller given for task(s) {', '.join(missing)}")
        if not 0 <= start <= stop:
            raise SimError(f"episode range {start}..{stop} is empty or negative")
        jobs: list[Job] = [(t, design.as_tuple(), i, episode_seed(seed, i)) for t in names for i in range(start, stop)]
        out = {t: (np.full(stop - start, np.nan), np.full((stop - start, 3), np.nan)) for t in names}
        if self._pool is None:
            raise SimError("the episode runner is closed")
        results = self._pool.imap_unordered(_run_job, jobs, chunksize=max(1, len(jobs) // (4 * self.workers)))
        for task, index, R, position in results:
            out[task][0][index - start] = R
            out[task][1][index - start] = position
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
