"""The report's numbers: the thesis's reference values, studies read back, designs evaluated
on fresh episodes, and the Table 3.1 / 3.2 equivalents, the universal-optimum check and the
slices."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from tumblebot.sim.evaluation.stats import mean_ci95, paired_p
from tumblebot.sim.optimize import (
    Objective,
    OptimizeError,
    StudyConfig,
    TrialRecord,
    best_candidate,
    episode_count,
    format_xi,
    front_optima,
    full_batch_results,
    load_config,
    load_study,
    promotions,
    study_drivers,
    value_at,
)
from tumblebot.sim.world.design import BOUNDS, PARAMETERS, THESIS_ROBOTS, Design
from tumblebot.sim.world.physics import PhysicsProfile
from tumblebot.sim.world.power import energy_per_metre

#: Thesis Table 3.1 (nav-flat): ξ → (x, y, z, l, R, e).
THESIS_TABLE_31: dict[str, tuple[float, float, float, float, float, float]] = {
    "0": (*THESIS_ROBOTS["0"].as_tuple(), 0.854, 6.05),
    "1": (*THESIS_ROBOTS["1"].as_tuple(), 0.857, 6.00),
    "3": (*THESIS_ROBOTS["3"].as_tuple(), 0.870, 5.20),
    "inf": (*THESIS_ROBOTS["inf"].as_tuple(), 0.853, 3.76),
}
#: Thesis Table 3.2: perturbation → (R, p).
THESIS_TABLE_32: dict[str, tuple[float, float | None]] = {
    "none": (0.854, None), "+x": (0.869, 0.46), "-x": (0.785, 1.9e-6), "+y": (0.868, 0.22), "-y": (0.837, 6.9e-4),
    "+z": (0.843, 0.278), "-z": (0.827, 8.9e-4), "+l": (0.823, 0.019), "-l": (0.813, 3.7e-4),
}
#: Thesis Table 3.1 p-values against the ξ = 0 robot.
THESIS_TABLE_31_P: dict[str, float | None] = {"0": None, "1": 0.33, "3": 0.08, "inf": 0.53}
PERTURBATION = 0.1  # m, as in the thesis
CONTROLLER_LABEL = {"policy": "each task's bundled policy",
                    "thesis-policy": "each task's bundled policy with the thesis's 9-number observation",
                    "goto": "goto (the hand-written navigation controller)",
                    "plan": "plan (goto with steadier estimates, the stronger hand-written navigation controller)"}


@dataclass
class Evaluated:
    """A design evaluated on the report's episodes."""

    design: Design
    R: dict[str, np.ndarray]
    e: float

    def mean(self, task: str) -> float:
        return float(np.mean(self.R[task]))

    def ci(self, task: str) -> tuple[float, float]:
        return mean_ci95(self.R[task])


@dataclass
class StudyResult:
    name: str
    config: StudyConfig
    objective: Objective
    tasks: list[str]  # tasks evaluated in the report (R is reported for them even when ξ = ∞)
    trials: list[dict[str, Any]]
    episodes: int
    best: Evaluated | None = None
    best_trial: int | None = None
    study_value: float | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    #: for one ξ read from a front study: that study's name (its episodes are shared)
    front_of: str | None = None

    @property
    def xi_label(self) -> str:
        return format_xi(self.objective.xi)



class Evaluator:
    """Evaluates designs on the report's episodes, with a cache and a progress bar."""

    def __init__(self, tasks: list[str], episodes: int, workers: int, seed: int, total: int, progress: bool,
                 controller: str = "policy", physics: PhysicsProfile | None = None,
                 allow_servo_mismatch: bool = False, policies: dict[str, Path] | None = None) -> None:
        from tumblebot.sim.control.policy import sha256_of
        from tumblebot.sim.evaluation.runner import EpisodeRunner

        drivers = study_drivers(controller, tasks, allow_servo_mismatch, policies=policies)
        self.policies = policies or {}
        #: task → SHA-256 of the ONNX policy that re-evaluates it (none for goto or a gait)
        self.policy_hashes = {t: sha256_of(Path(d.name)) for t, d in drivers.items() if d.kind == "onnx"}
        self.runner = EpisodeRunner(drivers, workers=workers, physics=physics) if tasks else None
        self.episodes, self.seed = episodes, seed
        self.tasks, self.workers, self.controller = tasks, workers, controller
        self.cache: dict[tuple[tuple[float, ...], str], np.ndarray] = {}
        self.bar: Any = None
        if progress and tasks:
            from tqdm import tqdm

            self.bar = tqdm(total=total, unit="design", desc="report", mininterval=0.5)

    def __call__(self, design: Design, tasks: list[str]) -> Evaluated:
        todo = [t for t in tasks if (design.as_tuple(), t) not in self.cache]
        if todo and self.runner is not None and design.can_tumble:
            for t, r in self.runner.run(design, todo, 0, self.episodes, self.seed).items():
                self.cache[(design.as_tuple(), t)] = r
        elif todo:  # a body that cannot tumble is not simulated: it has no R
            for t in todo:
                self.cache[(design.as_tuple(), t)] = np.full(self.episodes, np.nan)
        if self.bar is not None:
            self.bar.update()
        return Evaluated(design, {t: self.cache[(design.as_tuple(), t)] for t in tasks}, energy_per_metre(design))

    def skip(self) -> None:
        if self.bar is not None:
            self.bar.update()

    def close(self) -> None:
        if self.bar is not None:
            self.bar.n = self.bar.total  # every design is evaluated (cached ones count once)
            self.bar.refresh()
            self.bar.close()
        if self.runner is not None:
            self.runner.close()


def load_result(storage: Any, name: str) -> StudyResult:
    """A single-ξ study read back (a front study is refused: use :func:`load_results`)."""
    results = load_results(storage, name)
    if len(results) != 1 or results[0].front_of is not None:
        raise OptimizeError(f"study {name!r} is a front study; read it with load_results(storage, name, xis)")
    return results[0]


def load_results(storage: Any, name: str, xis: tuple[float, ...] | None = None,
                 strict: bool = True) -> list[StudyResult]:
    """A study read back: one result, or for a front study one per ``ξ`` of ``xis`` (default
    the ξ it was made for), each with the optimum :func:`front_optima` reads for that ξ.
    ``xis`` for a single-ξ study is refused if ``strict``, else ignored."""
    from optuna.trial import TrialState

    study = load_study(storage, name)
    config = load_config(study)
    if config is None:
        raise OptimizeError(f"study {name!r} was not made by tumblebot optimize")
    objective = config.objective()
    if xis is not None and not objective.front and strict:
        raise OptimizeError(f"--xi reads optima from front studies (optimize --front); study {name!r} was made "
                            f"for ξ = {format_xi(objective.xi)} alone")
    tasks = [t for t, w in objective.weights.items() if w > 0]
    trials: list[dict[str, Any]] = []
    infeasible: list[int] = []  # trials that ran no episodes: the legs cannot tumble the body
    for t in study.get_trials(deepcopy=False):
        rec = TrialRecord.of(t)
        if t.state == TrialState.COMPLETE and rec.infeasible is not None:
            infeasible.append(t.number)
        if t.state != TrialState.COMPLETE or rec.infeasible is not None:
            continue
        trials.append({"number": t.number, "value": t.value, "params": dict(t.params), "e": rec.e,
                       "mean_R": rec.mean_R, "batch": rec.batch, "datetime": t.datetime_complete})
    episodes = episode_count(study)
    full = sorted(full_batch_results(study), key=lambda c: c.trial)
    promoted = sorted(promotions(study))
    if not objective.front:
        result = StudyResult(name, config, objective, tasks, trials, episodes)
        result.extra["full_batch"] = [(c.trial, c.value) for c in full]
        result.extra["promoted"] = promoted
        result.extra["infeasible"] = infeasible
        result.extra["infeasible"] = infeasible
        best = best_candidate(study)
        if best is not None:
            result.best_trial, result.study_value = best.trial, best.value
            result.extra["best_design"] = best.design
        return [result]
    out = []
    optima = front_optima(study, xis or objective.front)
    for xi in xis or objective.front:
        at = objective.at(xi)
        # a trial's value is its ξ = 0 objective (mean weighted R); the thesis wrapper divides it
        seen = [{**t, "value": -t["e"] if math.isinf(xi) else t["value"] / (t["e"] + 1.0) ** xi} for t in trials
                if t["e"] is not None and t["value"] is not None]
        result = StudyResult(f"{name} @ ξ={format_xi(xi)}", config, at, tasks, seen, episodes, front_of=name)
        result.extra["full_batch"] = [(c.trial, value_at(c, at)) for c in full]
        result.extra["full_R"] = {c.trial: np.sum([objective.weights[k] * np.asarray(v) for k, v in c.R.items()],
                                                  axis=0).tolist() for c in full}
        result.extra["promoted"] = promoted
        result.extra["infeasible"] = infeasible
        if xi in optima:
            best = optima[xi]
            result.best_trial, result.study_value = best.trial, best.value
            result.extra["best_design"] = best.design
        out.append(result)
    return out


def check_policies(results: list[StudyResult], controller: str, hashes: dict[str, str]) -> None:
    """Refuse to re-evaluate a study with a policy other than the one it recorded (when
    the report uses the studies' own kind of controller): its optimum was found with that
    file, and the report would quietly describe another. ``--policy TASK=FILE`` pins it."""
    for r in results:
        if r.config.controller != controller:
            continue  # the report was asked for another controller (--gait, --thesis-policies)
        for task, recorded in r.config.policies.items():
            if task in hashes and hashes[task] != recorded:
                raise OptimizeError(f"study {r.name!r} ran {task} with the policy of SHA-256 {recorded[:12]}…, not "
                                    f"this one ({hashes[task][:12]}…): give the file it used with --policy "
                                    f"{task}=FILE, or re-evaluate with another controller (--gait goto)")


def common_controller(results: list[StudyResult], controller: str | None, physics: PhysicsProfile | None
                       ) -> tuple[str, PhysicsProfile]:
    """The controller and physics profile of the re-evaluation: as given, else the studies' own."""
    if controller is None:
        used = sorted({r.config.controller for r in results})
        if len(used) > 1:
            raise OptimizeError(f"the studies were run with different controllers ({', '.join(used)}); "
                                "choose one for the report with --gait (goto) or run separate reports")
        controller = used[0]
    if physics is None:
        profiles = {r.config.profile() for r in results}
        if len(profiles) > 1:
            raise OptimizeError("the studies were run under different physics ("
                                + "; ".join(sorted(s.describe() for s in profiles))
                                + "); choose one with --physics (or --motor-model/--stall-torque)")
        physics = profiles.pop()
    return controller, physics



def reference_study(usable: list[StudyResult]) -> StudyResult:
    """The ξ = 0 study of the first study's tasks, else the first study: the 'ξ = 0 robot'."""
    first = usable[0]
    for r in usable:
        if r.objective.xi == 0 and r.objective.weights == first.objective.weights:
            return r
    return first


def build_table31(usable: list[StudyResult], reference: StudyResult, task: str) -> list[dict[str, Any]]:
    rows = []
    assert reference.best is not None
    for r in sorted(usable, key=lambda s: (s.objective.xi, s.name)):
        assert r.best is not None
        row: dict[str, Any] = {"study": r.name, "tasks": r.tasks, "xi": r.xi_label,
                               "design": r.best.design.as_dict(),
                               "e": r.best.e, "trial": r.best_trial, "study_objective": r.study_value,
                               "study_episodes": r.episodes,
                               "R": {t: r.best.mean(t) for t in r.tasks}, "ci95": {t: r.best.ci(t) for t in r.tasks}}
        if task in r.best.R:
            row["p_vs_reference"] = None if r is reference else paired_p(r.best.R[task], reference.best.R[task])
        if r.tasks == ["nav-flat"] and r.xi_label in THESIS_TABLE_31:
            x, y, z, l, R, e = THESIS_TABLE_31[r.xi_label]  # noqa: E741
            row["thesis"] = {"x": x, "y": y, "z": z, "l": l, "R": R, "e": e, "p": THESIS_TABLE_31_P[r.xi_label]}
        rows.append(row)
    return rows


def build_table32(ev: Evaluator, reference: StudyResult, task: str) -> list[dict[str, Any]]:
    assert reference.best is not None
    base = reference.best.design
    rows: list[dict[str, Any]] = [{"change": "none", "design": base.as_tuple(), "in_bounds": True,
                                   "R": reference.best.mean(task), "p": None, "can_tumble": base.can_tumble,
                                   "thesis_R": THESIS_TABLE_32["none"][0]}]
    for name in PARAMETERS:
        for sign in (+1, -1):
            values = list(base.as_tuple())
            values[PARAMETERS.index(name)] += sign * PERTURBATION
            label = f"{'+' if sign > 0 else '-'}{name}"
            row: dict[str, Any] = {"change": label, "design": tuple(values), "thesis_R": THESIS_TABLE_32[label][0],
                                   "thesis_p": THESIS_TABLE_32[label][1]}
            if min(values) <= 0:
                row.update(in_bounds=False, R=None, p=None, can_tumble=False, note="not a body (a length <= 0)")
                ev.skip()
            else:
                w = Design.from_sequence(values, allow_out_of_bounds=True)
                res = ev(w, [task])
                row.update(in_bounds=w.in_bounds(), can_tumble=w.can_tumble, e=res.e)
                if w.can_tumble:
                    row.update(R=res.mean(task), p=paired_p(res.R[task], reference.best.R[task]))
                else:
                    row.update(R=None, p=None, note="cannot tumble (l < r)")
            rows.append(row)
    return rows


def universal_check(ev: Evaluator, single: list[StudyResult], tasks: list[str]) -> dict[str, Any]:
    """Evaluate each task's optimum on every task: is one robot best for all of them?"""
    if len(tasks) < 2:
        return {"checked": False, "reason": f"needs single-task studies for at least two tasks; have "
                                            f"{', '.join(tasks) or 'none'}"}
    optimum: dict[str, StudyResult] = {}
    for r in single:  # the first study of each task (ξ = 0 preferred) stands for it
        t = r.tasks[0]
        if t not in optimum or (r.objective.xi == 0 and optimum[t].objective.xi != 0):
            optimum[t] = r
    matrix: dict[str, dict[str, Any]] = {}
    tied = True
    for task in tasks:
        own = optimum[task].extra["best_design"]
        own_R = ev(own, [task]).R[task]
        matrix[task] = {}
        for other in tasks:
            w = optimum[other].extra["best_design"]
            R = ev(w, [task]).R[task]
            p = None if other == task else paired_p(R, own_R)
            matrix[task][other] = {"R": float(np.mean(R)), "p_vs_own_optimum": p}
            if p is not None and p < 0.05:
                tied = False
    return {"checked": True, "optima": {t: optimum[t].extra["best_design"].as_tuple() for t in tasks},
            "studies": {t: optimum[t].name for t in tasks}, "matrix": matrix, "same_robot": tied}


def one_parameter_slices(ev: Evaluator, reference: StudyResult, points: int) -> dict[str, Any]:
    """The reference objective along each parameter through the optimum, the others fixed."""
    assert reference.best is not None
    base = reference.best.design
    obj = reference.objective
    out: dict[str, Any] = {"study": reference.name, "optimum": base.as_tuple(), "parameters": {}}
    for name in PARAMETERS:
        lo, hi = BOUNDS[name]
        rows: list[dict[str, Any]] = []
        for v in np.linspace(lo, hi, points):
            values = list(base.as_tuple())
            values[PARAMETERS.index(name)] = float(v)
            w = Design.from_sequence(values)
            res = ev(w, reference.tasks)
            if not w.can_tumble:
                rows.append({"value": float(v), "objective": None, "ci95": None, "can_tumble": False})
                continue
            per = obj.per_episode(res.R, res.e)
            half = 1.96 * float(np.std(per, ddof=1)) / math.sqrt(len(per)) if len(per) > 1 else 0.0
            mean = float(np.mean(per))
            rows.append({"value": float(v), "objective": mean, "ci95": [mean - half, mean + half], "can_tumble": True})
        out["parameters"][name] = rows
    return out


def rebuild_pairs(usable: list[StudyResult], physics: PhysicsProfile
                  ) -> tuple[list[tuple[StudyResult, StudyResult]], str]:
    """For "would I still build it?": each study optimised under ``physics`` with the study
    of the same objective optimised under ``thesis``. Returns the pairs, and when there
    are none, a line that says what is missing."""
    from tumblebot.sim.world.physics import THESIS

    if physics.same_as(THESIS):
        return [], ""
    mine = [r for r in usable if r.config.profile().same_as(physics)]
    theirs = [r for r in usable if r.config.profile().same_as(THESIS)]

    def key(r: StudyResult) -> tuple[Any, ...]:
        o = r.objective
        return tuple(sorted(o.weights.items())), o.xi, o.variant

    pairs = [(t, m) for m in mine for t in theirs if key(t) == key(m)]
    if pairs:
        return pairs, ""
    if not mine:
        return [], (f"none of these studies was optimised under {physics.name}: run tumblebot optimize with "
                    f"--physics and give that study to --study too")
    return [], (f"no study of the same objective was optimised under thesis: give one with --study to compare "
                f"{', '.join(r.name for r in mine)} with")


def would_i_still_build_it(pairs: list[tuple[StudyResult, StudyResult]], ev: Evaluator, physics: PhysicsProfile,
                           allow_servo_mismatch: bool = False) -> list[dict[str, Any]]:
    """The thesis-world optimum and the optimum under ``physics`` (``ev``'s world), each
    scored under both worlds on the same episodes (per-episode objective, paired t-test),
    and the verdict."""
    from tumblebot.sim.world.physics import THESIS

    ev_thesis = Evaluator(list(ev.tasks), ev.episodes, ev.workers, ev.seed, 0, False, ev.controller, THESIS,
                          allow_servo_mismatch, ev.policies)
    try:
        return [_rebuild_row(thesis_study, mine, ev, ev_thesis, physics) for thesis_study, mine in pairs]
    finally:
        ev_thesis.close()


def _rebuild_row(thesis_study: StudyResult, mine: StudyResult, ev: Evaluator, ev_thesis: Evaluator,
                 physics: PhysicsProfile) -> dict[str, Any]:
    assert thesis_study.best is not None and mine.best is not None
    objective = mine.objective
    tasks = objective.tasks
    w_t, w_m = thesis_study.best.design, mine.best.design
    score: dict[str, dict[str, np.ndarray]] = {}
    for world, evaluator in (("physics", ev), ("thesis", ev_thesis)):
        score[world] = {}
        for label, w in (("thesis_optimum", w_t), ("physics_optimum", w_m)):
            evaluated = evaluator(w, tasks)
            score[world][label] = objective.per_episode(evaluated.R, evaluated.e) if tasks else \
                np.array([-evaluated.e])
    row: dict[str, Any] = {"objective": objective.describe(), "thesis_study": thesis_study.name,
                           "physics_study": mine.name, "thesis_optimum": w_t.as_dict(),
                           "physics_optimum": w_m.as_dict()}
    for world in ("physics", "thesis"):
        a, b = score[world]["thesis_optimum"], score[world]["physics_optimum"]
        row[world] = {"thesis_optimum": float(np.nanmean(a)), "physics_optimum": float(np.nanmean(b)),
                      "p": paired_p(a, b)}
    under = row["physics"]
    better = under["physics_optimum"] > under["thesis_optimum"]
    significant = under["p"] is not None and under["p"] < 0.05
    if significant and better:
        row["verdict"] = (f"No: under {physics.name} the optimum found for it scores "
                          f"{under['physics_optimum']:.3f} against the thesis-world optimum's "
                          f"{under['thesis_optimum']:.3f} (paired p = {under['p']:.3g}): build the recalibrated "
                          "robot.")
    elif significant:
        row["verdict"] = (f"Yes: under {physics.name} the thesis-world optimum scores better "
                          f"({under['thesis_optimum']:.3f} against {under['physics_optimum']:.3f}, paired p = "
                          f"{under['p']:.3g}); the search under {physics.name} did not find better.")
    else:
        p = "n/a" if under["p"] is None else f"{under['p']:.3g}"
        row["verdict"] = (f"Yes: under {physics.name} the thesis-world optimum ties the optimum found for it "
                          f"({under['thesis_optimum']:.3f} against {under['physics_optimum']:.3f}, paired p = "
                          f"{p}): the robot you built is still the one to build.")
    return row
