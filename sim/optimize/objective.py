"""The objective: tasks and weights, ξ, the wrapper; parsing of their command-line forms; the
optimiser's errors and stop flag."""

from __future__ import annotations

import contextlib
import math
import signal
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from tumblebot import interrupts
from tumblebot.sim.errors import SimError, UnknownTaskError
from tumblebot.sim.evaluation.score import VARIANTS, Variant, wrap_reward
from tumblebot.sim.world.tasks import get_task

if TYPE_CHECKING:

    pass



class OptimizeError(SimError):
    """A bad optimisation request: bad tasks or weights, a storage that cannot be opened,
    or a study that was created for a different objective."""


class StopRequested(Exception):
    """Raised at a safe point after Ctrl-C (or SIGTERM) asked the run to stop."""


class StopFlag:
    """Ctrl-C and SIGTERM only set this flag; the optimiser looks at it at safe points
    (between episodes, before asking for a trial) and stops there, marking an unfinished
    trial interrupted so it is redone. Use :meth:`installed` around the work."""

    def __init__(self) -> None:
        self._event = threading.Event()

    def __call__(self) -> bool:
        return self._event.is_set()

    def set(self) -> None:
        self._event.set()

    @contextlib.contextmanager
    def installed(self) -> Iterator[StopFlag]:
        """Route SIGINT and SIGTERM to this flag while the block runs (main thread only)."""
        if threading.current_thread() is not threading.main_thread():
            yield self
            return
        previous = {sig: signal.signal(sig, lambda _sig, _frame: self.set())
                    for sig in (signal.SIGINT, signal.SIGTERM)}
        if interrupts.take():  # Ctrl-C while the command was starting (tumblebot.interrupts)
            self.set()
        try:
            yield self
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)



# --------------------------------------------------------------------------- objective
def parse_tasks(text: str) -> dict[str, float]:
    """Parse ``"nav-flat=1,incline=0.5"`` into task → weight (a bare name weighs 1)."""
    weights: dict[str, float] = {}
    if not text.strip():
        raise OptimizeError("--tasks is empty; give e.g. nav-flat=1,incline=0.5")
    for part in text.split(","):
        name, sep, raw = part.partition("=")
        name = name.strip()
        if not name:
            raise OptimizeError(f"--tasks {text!r}: an entry has no task name")
        try:
            task = get_task(name).name
        except UnknownTaskError as exc:
            raise OptimizeError(f"--tasks: {exc}") from None
        if task in weights:
            raise OptimizeError(f"--tasks: task {task!r} is given twice")
        if sep:
            try:
                weight = float(raw)
            except ValueError:
                raise OptimizeError(f"--tasks: weight {raw.strip()!r} of {task} is not a number") from None
        else:
            weight = 1.0
        if not math.isfinite(weight) or weight < 0:
            raise OptimizeError(f"--tasks: weight {weight} of {task} must be a finite number >= 0")
        weights[task] = weight
    if not any(weights.values()):
        raise OptimizeError("--tasks: at least one weight must be positive")
    return weights


def parse_xi(text: str) -> float:
    """ξ from a command line: a number ``>= 0``, or ``inf`` (minimise ``e(w)`` alone)."""
    if text.strip().lower() in ("inf", "infinity", "∞"):
        return math.inf
    try:
        xi = float(text)
    except ValueError:
        raise OptimizeError(f"--xi {text!r} is not a number (use a value >= 0, or inf)") from None
    if math.isnan(xi) or xi < 0:
        raise OptimizeError(f"--xi {text!r} must be >= 0 (or inf)")
    return xi


def format_xi(xi: float) -> str:
    return "inf" if math.isinf(xi) else f"{xi:g}"


def parse_xi_list(text: str) -> tuple[float, ...]:
    """``"0,1,3,inf"`` → ``(0.0, 1.0, 3.0, inf)``: distinct values, in the order given."""
    values = tuple(parse_xi(part) for part in text.split(",") if part.strip())
    if not values:
        raise OptimizeError(f"--xi {text!r}: give one or more values, e.g. 0,1,3,inf")
    if len(set(values)) != len(values):
        raise OptimizeError(f"--xi {text!r}: a value is given twice")
    return values


@dataclass(frozen=True)
class Objective:
    """What a study maximises: weighted tasks, ``ξ`` and the wrapper variant.

    A *front* study (``front`` = the ``ξ`` values it serves, e.g. ``(0, 1, 3, inf)``) searches
    the Pareto front of high ``R`` and low ``e(w)`` instead of one ``ξ``: each trial's value
    is its ``ξ = 0`` objective (the weighted mean ``R``; ``xi`` is 0), its acquisition aims at
    the listed finite ``ξ`` (the largest relative improvement for any of them), and the
    optimum of any ``ξ`` is read from it afterwards
    (:func:`~tumblebot.sim.optimize.trials.front_optima`). ``ξ = ∞`` costs no search: it is
    the design of least ``e(w)``, which the study evaluates first."""

    weights: dict[str, float]
    xi: float
    variant: Variant = "thesis"
    front: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        if self.variant not in VARIANTS:
            raise OptimizeError(f"wrapper variant {self.variant!r} must be one of {VARIANTS}")
        if self.front and self.xi != 0:
            raise OptimizeError("a front study has no single ξ (its trials are told their ξ = 0 value)")

    @property
    def targets(self) -> tuple[float, ...]:
        """The finite ``ξ`` the acquisition serves: the front's, or this study's ``ξ``."""
        if self.front:
            return tuple(x for x in self.front if math.isfinite(x)) or (0.0,)
        return (self.xi,)

    def at(self, xi: float) -> Objective:
        """The single-``ξ`` objective with these tasks and wrapper."""
        return Objective(dict(self.weights), xi, self.variant)

    @property
    def tasks(self) -> list[str]:
        """Tasks that need episodes (positive weight; none when ``ξ = ∞``)."""
        if math.isinf(self.xi):
            return []
        return [t for t, wt in self.weights.items() if wt > 0]

    def per_episode(self, R: dict[str, np.ndarray], e: float) -> np.ndarray:
        """``Σ_i λ_i·f_i`` of each episode of a batch (``-e`` when ``ξ = ∞``)."""
        if math.isinf(self.xi):
            return np.array([-e])
        n = len(next(iter(R.values())))
        total = np.zeros(n)
        for task in self.tasks:
            total += self.weights[task] * np.array([wrap_reward(float(r), e, self.xi, self.variant) for r in R[task]])
        return total

    def describe(self) -> str:
        tasks = ",".join(f"{t}={wt:g}" for t, wt in self.weights.items())
        if self.front:
            return f"{tasks}, front for ξ={','.join(format_xi(x) for x in self.front)} ({self.variant} wrapper)"
        return f"{tasks} ξ={format_xi(self.xi)} ({self.variant} wrapper)"
