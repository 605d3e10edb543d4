"""Recipes: how many trials, batches and screening, and when the GP takes over."""

from __future__ import annotations

from dataclasses import dataclass

from tumblebot.sim.optimize.objective import Objective, OptimizeError


# --------------------------------------------------------------------------- recipes
@dataclass(frozen=True)
class Recipe:
    """How many designs, with how many episodes each.

    Attributes:
        name: ``standard``, ``thesis`` or ``efficient``.
        trials: designs to evaluate (infeasible ones included).
        batch: the full batch ``B``, episodes per task for a final verdict on a design.
        startup: feasible designs drawn at random before the GP takes over.
        screen_batch: episodes per task for an ordinary trial (``batch`` unless efficient).
        promote_every: efficient only: after every this many trials, the best design not yet
            evaluated on the full batch gets the remaining ``batch - screen_batch`` episodes.
        final_promotions: efficient only: designs promoted when the trials are done.

    The efficient recipe's GP models each task's R with e(w) exact (:meth:`surrogate`);
    the others use Optuna's GP-logEI on the noisy objective.
    """

    name: str
    trials: int
    batch: int
    startup: int
    screen_batch: int
    promote_every: int = 0
    final_promotions: int = 0

    def __post_init__(self) -> None:
        if self.trials < 1:
            raise OptimizeError(f"--trials {self.trials} must be at least 1")
        if self.batch < 1:
            raise OptimizeError(f"--batch {self.batch} must be at least 1 episode")
        if not self.startup >= 0:
            raise OptimizeError(f"--startup {self.startup} must be >= 0")
        if not 1 <= self.screen_batch <= self.batch:
            raise OptimizeError(f"screening batch {self.screen_batch} must be between 1 and --batch {self.batch}")

    @classmethod
    def make(cls, name: str, trials: int | None, batch: int | None, startup: int | None = None) -> Recipe:
        """Build a named recipe; ``thesis`` fixes every number and refuses others."""
        if name == "thesis":
            if any(v is not None and v != fixed for v, fixed in ((trials, 2000), (batch, 240), (startup, 1000))):
                raise OptimizeError("--recipe thesis fixes --trials 2000 --batch 240 --startup 1000; "
                                    "use --recipe standard or efficient for other numbers")
            return cls("thesis", 2000, 240, 1000, 240)
        if trials is None or batch is None:
            raise OptimizeError(f"--recipe {name} needs --trials and --batch")
        if trials < 1:
            raise OptimizeError(f"--trials {trials} must be at least 1")
        if batch < 1:
            raise OptimizeError(f"--batch {batch} must be at least 1 episode")
        if startup is None:
            startup = max(1, min(trials // 2, 20))
        if name == "standard":
            return cls("standard", trials, batch, startup, batch)
        if name == "efficient":
            screen = max(min(batch, 4), batch // 15)
            return cls("efficient", trials, batch, startup, screen, promote_every=10,
                       final_promotions=min(3, trials))
        raise OptimizeError(f"--recipe {name!r} must be standard, thesis or efficient")

    def surrogate(self, objective: Objective | None) -> str:
        """Which GP proposes the designs: ``"R"`` (each task's R modelled, e(w) exact: the
        efficient recipe, and every front study) or ``"logEI"`` (Optuna's GP-logEI on the
        noisy objective)."""
        if objective is None or not objective.tasks:
            return "logEI"
        return "R" if self.name == "efficient" or objective.front else "logEI"
