"""The package's one worker pool: processes that each build their state once, then run jobs.

Everything that runs episodes in parallel uses :class:`WorkerPool`: the evaluation and
the optimiser (:class:`tumblebot.sim.evaluation.runner.EpisodeRunner`, one environment and one
controller per task, reused across designs), the calibration (the logged trials, replayed
under many physics profiles), and the teacher's sweep and clairvoyant search in training.
Each worker calls ``setup(*args)`` once (say, to build an environment) and then
``fn(state, job)`` for every job it is given, with ``fn`` a module-level function (it
travels to the worker by name). Workers are started with ``forkserver`` (no fork of a
process holding a physics server or torch threads) and ignore Ctrl-C: the parent stops
at a safe point between results and closes the pool. With ``workers=1`` the jobs run in
this process, whose Ctrl-C handling is left alone.
"""

from __future__ import annotations

import multiprocessing as mp
import signal
from collections.abc import Callable, Iterable, Iterator
from types import TracebackType
from typing import Any, Generic, TypeVar

from tumblebot.sim.errors import SimError

State = TypeVar("State")
Job = TypeVar("Job")
Result = TypeVar("Result")

_state: Any = None  #: in a pool process: what ``setup`` built


def _init(setup: Callable[..., Any], args: tuple[Any, ...]) -> None:
    global _state
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C and closes the pool
    _state = setup(*args)


def _call(item: tuple[Callable[[Any, Any], Any], Any]) -> Any:
    fn, job = item
    return fn(_state, job)


class WorkerPool(Generic[State]):
    """``workers`` processes, each holding what ``setup(*args)`` returned.

    Args:
        setup: builds a worker's state (module-level, or a class); called once per worker.
        args: its arguments (picklable).
        workers: worker processes (1 runs everything in this process).
    """

    def __init__(self, setup: Callable[..., State], args: tuple[Any, ...] = (), workers: int = 1) -> None:
        if workers < 1:
            raise SimError(f"workers={workers} must be at least 1")
        self.workers = workers
        self._pool: Any = None
        self._local: State | None = None
        if workers > 1:
            self._pool = mp.get_context("forkserver").Pool(workers, initializer=_init, initargs=(setup, args))
        else:
            self._local = setup(*args)

    def imap_unordered(self, fn: Callable[[State, Job], Result], jobs: Iterable[Job],
                       chunksize: int = 1) -> Iterator[Result]:
        """``fn(state, job)`` for every job, results as they finish (in job order in this process)."""
        if self._pool is None:
            if self._local is None:
                raise SimError("the worker pool is closed")
            local = self._local
            return (fn(local, job) for job in jobs)
        return self._pool.imap_unordered(_call, [(fn, job) for job in jobs], chunksize=chunksize)  # type: ignore[no-any-return]

    def map(self, fn: Callable[[State, Job], Result], jobs: Iterable[Job], chunksize: int = 1) -> list[Result]:
        """``fn(state, job)`` for every job, in job order."""
        if self._pool is None:
            return list(self.imap_unordered(fn, jobs))
        return self._pool.map(_call, [(fn, job) for job in jobs], chunksize=chunksize)  # type: ignore[no-any-return]

    def close(self) -> None:
        """Stop the workers (now, mid-job if need be), or close this process's state."""
        if self._pool is not None:
            self._pool.terminate()
            self._pool.join()
            self._pool = None
        if self._local is not None:
            close = getattr(self._local, "close", None)
            if callable(close):
                close()
            self._local = None

    def __enter__(self) -> WorkerPool[State]:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
