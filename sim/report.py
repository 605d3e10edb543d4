"""The optimisation report: thesis Tables 3.1 and 3.2 reproduced in our simulator, with plots.

``write_report`` reads finished studies and writes ``report.md``, ``report.json`` and PNG
plots into a folder. Every number in the tables comes from a fresh evaluation (seed
``seed``, which should differ from the studies' seed): the optimum of a search is the
design whose batch happened to score best, and re-using that batch would overstate it.
All designs are evaluated on the same episodes (common random numbers), so two designs are
compared with a paired t-test on per-episode final-state rewards.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from tumblebot.sim.design import BOUNDS, PARAMETERS, THESIS_ROBOTS, Design
from tumblebot.sim.evaluate import Servo
from tumblebot.sim.optimize import (
    Objective,
    OptimizeError,
    StudyConfig,
    best_candidate,
    episode_count,
    format_xi,
    full_batch_results,
    load_config,
    load_study,
    open_storage,
    promotions,
    study_controllers,
)
from tumblebot.sim.power import energy_per_metre
from tumblebot.sim.stats import mean_ci95

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
CONTROLLER_LABEL = {"policy": "each task's bundled policy", "goto": "goto (the hand-written navigation controller)"}


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


def paired_p(a: np.ndarray, b: np.ndarray) -> float | None:
    """Two-sided paired t-test p-value (episodes shared by common random numbers)."""
    from scipy import stats

    if len(a) < 2 or len(a) != len(b):
        return None
    d = np.asarray(a) - np.asarray(b)
    if np.allclose(d, 0.0):
        return 1.0
    return float(stats.ttest_rel(a, b).pvalue)


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

    @property
    def xi_label(self) -> str:
        return format_xi(self.objective.xi)


def _fmt(v: float | None, digits: int = 3) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "n/a"
    if isinstance(v, float) and math.isinf(v):
        return "inf"
    return f"{v:.{digits}f}"


def _fmt_p(p: float | None) -> str:
    if p is None:
        return "n/a"
    s = f"{p:.2g}"
    return f"**{s}**" if p < 0.05 else s


class _Evaluator:
    """Evaluates designs on the report's episodes, with a cache and a progress bar."""

    def __init__(self, tasks: list[str], episodes: int, workers: int, seed: int, total: int, progress: bool,
                 controller: str = "policy", servo: Servo | None = None, allow_servo_mismatch: bool = False) -> None:
        from tumblebot.sim.runner import EpisodeRunner

        self.runner = (EpisodeRunner(study_controllers(controller, tasks, allow_servo_mismatch), workers=workers,
                                     servo=servo)
                       if tasks else None)
        self.episodes, self.seed = episodes, seed
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


def _load(storage: Any, name: str) -> StudyResult:
    from optuna.trial import TrialState

    study = load_study(storage, name)
    config = load_config(study)
    if config is None:
        raise OptimizeError(f"study {name!r} was not made by tumblebot optimize")
    objective = config.objective()
    tasks = [t for t, w in objective.weights.items() if w > 0]
    trials = []
    for t in study.get_trials(deepcopy=False):
        if t.state != TrialState.COMPLETE or "infeasible" in t.user_attrs:
            continue
        trials.append({"number": t.number, "value": t.value, "params": dict(t.params),
                       "batch": t.user_attrs.get("batch", 0), "datetime": t.datetime_complete})
    best = best_candidate(study)
    result = StudyResult(name, config, objective, tasks, trials, episode_count(study))
    full = sorted(full_batch_results(study), key=lambda c: c.trial)
    result.extra["full_batch"] = [(c.trial, c.value) for c in full]
    result.extra["promoted"] = sorted(promotions(study))
    if best is not None:
        result.best_trial, result.study_value = best.trial, best.value
        result.extra["best_design"] = best.design
    return result


def _common_controller(results: list[StudyResult], controller: str | None, servo: Servo | None
                       ) -> tuple[str, Servo]:
    """The controller and servo of the re-evaluation: as given, else the studies' own."""
    if controller is None:
        used = sorted({r.config.controller for r in results})
        if len(used) > 1:
            raise OptimizeError(f"the studies were run with different controllers ({', '.join(used)}); "
                                "choose one for the report with --gait (goto) or run separate reports")
        controller = used[0]
    if servo is None:
        servos = {r.config.servo() for r in results}
        if len(servos) > 1:
            raise OptimizeError("the studies were run with different servos ("
                                + "; ".join(sorted(s.describe() for s in servos))
                                + "); choose one with --motor-model/--stall-torque")
        servo = servos.pop()
    return controller, servo


def write_report(storage_url: str, studies: list[str], out_dir: Path, episodes: int | None = None,
                 workers: int = 1, seed: int = 1, slice_points: int = 7, progress: bool = True,
                 controller: str | None = None, servo: Servo | None = None,
                 allow_servo_mismatch: bool = False) -> Path:
    """Evaluate and plot the studies; returns the path of ``report.md``.

    Every design is re-evaluated with one controller and one servo, so the tables compare
    like with like: ``controller`` (``"policy"``, ``goto`` or a gait) and ``servo`` default
    to what the studies used, which must then agree."""
    if not studies:
        raise OptimizeError("give at least one --study")
    if len(set(studies)) != len(studies):
        raise OptimizeError("a --study is given twice")
    if episodes is not None and episodes < 2:
        raise OptimizeError(f"--episodes {episodes} must be at least 2 (t-tests need two episodes)")
    if slice_points < 2:
        raise OptimizeError(f"--slice-points {slice_points} must be at least 2")
    if workers < 1:
        raise OptimizeError(f"--workers {workers} must be at least 1")
    storage = open_storage(storage_url, must_exist=True)
    results = [_load(storage, name) for name in studies]
    usable = [r for r in results if "best_design" in r.extra]
    if not usable:
        raise OptimizeError("none of the studies has a finished design yet; run tumblebot optimize first")
    if episodes is None:
        episodes = max(2, max(r.config.batch for r in results))
    all_tasks = sorted({t for r in results for t in r.tasks})
    reference = _reference(usable)
    ref_task = reference.tasks[0]
    single = [r for r in usable if len(r.tasks) == 1]
    universal_tasks = sorted({r.tasks[0] for r in single})
    total = len(usable) + 9 + len(PARAMETERS) * slice_points + len(universal_tasks) ** 2
    out_dir.mkdir(parents=True, exist_ok=True)
    controller, servo = _common_controller(results, controller, servo)
    ev = _Evaluator(all_tasks, episodes, workers, seed, total, progress, controller, servo, allow_servo_mismatch)
    try:
        for r in usable:
            r.best = ev(r.extra["best_design"], r.tasks)
        assert reference.best is not None
        table31 = _table31(usable, reference, ref_task)
        table32 = _table32(ev, reference, ref_task)
        universal = _universal(ev, single, universal_tasks)
        slices = _slices(ev, reference, slice_points)
    finally:
        ev.close()
    data = {"storage": storage_url, "studies": [r.name for r in results], "episodes": episodes, "seed": seed,
            "reference_study": reference.name, "reference_task": ref_task,
            "study_episodes": {r.name: r.episodes for r in results},
            "controller": controller, "servo": servo.as_dict(),
            "table31": table31, "table32": table32, "universal": universal, "slices": slices}
    plots = _plots(results, reference, slices, out_dir)
    text = _markdown(results, reference, ref_task, data, plots)
    (out_dir / "report.md").write_text(text)
    from tumblebot.sim.optimize import to_json

    (out_dir / "report.json").write_text(to_json(data) + "\n")
    return out_dir / "report.md"


def _reference(usable: list[StudyResult]) -> StudyResult:
    """The ξ = 0 study of the first study's tasks, else the first study: the 'ξ = 0 robot'."""
    first = usable[0]
    for r in usable:
        if r.objective.xi == 0 and r.objective.weights == first.objective.weights:
            return r
    return first


def _table31(usable: list[StudyResult], reference: StudyResult, task: str) -> list[dict[str, Any]]:
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


def _table32(ev: _Evaluator, reference: StudyResult, task: str) -> list[dict[str, Any]]:
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


def _universal(ev: _Evaluator, single: list[StudyResult], tasks: list[str]) -> dict[str, Any]:
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


def _slices(ev: _Evaluator, reference: StudyResult, points: int) -> dict[str, Any]:
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


# ------------------------------------------------------------------------------- plots
def _plot_objective_vs_trial(plt: Any, results: list[StudyResult]) -> Any:
    """Each study's objective per trial: screening values, promoted trials, the best full-batch value."""
    fig, axes = plt.subplots(len(results), 1, figsize=(7, 2.6 * len(results)), squeeze=False)
    for ax, r in zip(axes[:, 0], results, strict=True):
        screened = r.config.screen_batch < r.config.batch
        n = [t["number"] for t in r.trials]
        v = [t["value"] for t in r.trials]
        ax.scatter(n, v, s=8, alpha=0.5, color="C0",
                   label=f"trial, on its {r.config.screen_batch}-episode screening batch" if screened
                   else f"trial ({r.config.batch} episodes)")
        full = r.extra.get("full_batch", [])
        promoted = set(r.extra.get("promoted", []))
        marked = [(k, val) for k, val in full if k in promoted]
        if marked:
            ax.scatter(*zip(*marked, strict=True), s=40, marker="D", facecolors="none", edgecolors="C2",
                       label=f"promoted: on the full {r.config.batch}-episode batch")
        if full:
            ks, vals = zip(*full, strict=True)
            ax.step(ks, np.maximum.accumulate(vals), where="post", color="C3", label="best full-batch value so far")
        ax.axvline(r.config.startup - 0.5, color="grey", ls=":", lw=1, label="GP takes over")
        ax.set_title(f"{r.name}: {r.objective.describe()}", fontsize=9)
        ax.set_xlabel("trial")
        ax.set_ylabel("objective")
        ax.legend(fontsize=7, loc="lower right")
    return fig


def _plot_best_design_vs_trial(plt: Any, results: list[StudyResult]) -> Any:
    """Each study's best design so far, per trial."""

    fig, axes = plt.subplots(len(results), 1, figsize=(7, 2.4 * len(results)), squeeze=False)
    for ax, r in zip(axes[:, 0], results, strict=True):
        best_v, best_p, hist = -math.inf, {}, []
        for t in r.trials:
            if t["value"] > best_v:
                best_v, best_p = t["value"], t["params"]
            hist.append((t["number"], *(best_p[p] for p in PARAMETERS)))
        if hist:
            arr = np.array(hist)
            for i, p in enumerate(PARAMETERS):
                ax.step(arr[:, 0], arr[:, i + 1], where="post", label=p)
        ax.set_title(f"{r.name}: best design so far", fontsize=9)
        ax.set_xlabel("trial")
        ax.set_ylabel("m")
        ax.legend(fontsize=7, ncol=4)
    return fig


def _plot_slices(plt: Any, reference: StudyResult, slices: dict[str, Any]) -> Any:
    """One-parameter slices through the optimum, with 95 % intervals."""

    fig, axes = plt.subplots(1, 4, figsize=(12, 3), sharey=True)
    for ax, p in zip(axes, PARAMETERS, strict=True):
        rows = slices["parameters"][p]
        ok = [s for s in rows if s["objective"] is not None]
        if ok:
            xs = [s["value"] for s in ok]
            ys = [s["objective"] for s in ok]
            lo = [s["objective"] - s["ci95"][0] for s in ok]
            ax.errorbar(xs, ys, yerr=lo, fmt="o-", ms=3, capsize=2)
        bad = [s["value"] for s in rows if s["objective"] is None]
        for b in bad:
            ax.axvline(b, color="grey", alpha=0.3, lw=4)
        ax.axvline(slices["optimum"][PARAMETERS.index(p)], color="C3", ls="--", lw=1)
        ax.set_xlabel(f"{p} (m)")
    axes[0].set_ylabel(f"objective ({reference.name})")
    fig.suptitle("one-parameter slices through the optimum (95 % CI; grey: cannot tumble)", fontsize=9)
    return fig


def _plot_energy(plt: Any, reference: StudyResult) -> Any:
    """e(w) over two planes through the optimum."""

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    assert reference.best is not None
    bx, by, bz, bl = reference.best.design.as_tuple()
    gy, gz = np.linspace(*BOUNDS["y"], 60), np.linspace(*BOUNDS["z"], 60)
    E = np.array([[energy_per_metre(Design(bx, y, z, bl)) for y in gy] for z in gz])
    _heat(axes[0], gy, gz, E, "y (m)", "z (m)", f"e(w) at x={bx:.3f}, l={bl:.3f}")
    axes[0].plot(by, bz, "r*", ms=12)
    gx, gl = np.linspace(*BOUNDS["x"], 60), np.linspace(*BOUNDS["l"], 60)
    E2 = np.array([[energy_per_metre(Design(x, by, bz, l)) for x in gx] for l in gl])  # noqa: E741
    _heat(axes[1], gx, gl, E2, "x (m)", "l (m)", f"e(w) at y={by:.3f}, z={bz:.3f}")
    axes[1].plot(bx, bl, "r*", ms=12)
    return fig


def _plots(results: list[StudyResult], reference: StudyResult, slices: dict[str, Any], out: Path) -> dict[str, str]:
    """Draw the report's figures into ``out``; returns name → file."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figures = {
        "objective_vs_trial": _plot_objective_vs_trial(plt, results),
        "best_design_vs_trial": _plot_best_design_vs_trial(plt, results),
        "slices": _plot_slices(plt, reference, slices),
        "energy": _plot_energy(plt, reference),
    }
    for name, fig in figures.items():
        fig.tight_layout()
        fig.savefig(out / f"{name}.png", dpi=110)
        plt.close(fig)
    return {name: f"{name}.png" for name in figures}


def _heat(ax: Any, xs: np.ndarray, ys: np.ndarray, E: np.ndarray, xl: str, yl: str, title: str) -> None:
    finite = np.where(np.isfinite(E), E, np.nan)
    masked = np.ma.masked_invalid(finite)
    # e(w) grows without bound near the no-tumble boundary: clip the colour scale at the 90th
    # percentile so the rest of the map is readable (values above it share the top colour).
    vmax = float(np.nanpercentile(finite, 90)) if np.isfinite(finite).any() else None
    im = ax.pcolormesh(xs, ys, masked, shading="auto", cmap="viridis", vmax=vmax)
    ax.figure.colorbar(im, ax=ax, label="e (W/m), clipped at the 90th percentile", extend="max")
    ax.set_xlabel(xl)
    ax.set_ylabel(yl)
    ax.set_title(title + " (white: cannot tumble)", fontsize=9)


# ------------------------------------------------------------------------------- text
def _markdown(results: list[StudyResult], reference: StudyResult, task: str, data: dict[str, Any],
              plots: dict[str, str]) -> str:
    E = data["episodes"]
    out: list[str] = [
        "# Design optimisation report", "",
        f"Storage `{data['storage']}`; studies {', '.join(f'`{r.name}`' for r in results)}.",
        f"Every R below is a fresh evaluation: {E} episodes per design and task, seed {data['seed']}, the same "
        "episodes for every design (common random numbers). p-values are two-sided paired t-tests on "
        "per-episode final-state R; p < 0.05 in bold.",
        f"Controller: {CONTROLLER_LABEL.get(data['controller'], data['controller'])}; "
        f"servo: {data['servo']['motor_model']} model, stall torque {data['servo']['stall_torque']:.3g} N·m.", "",
        "## Studies", "",
        "| study | objective | recipe | batch | feasible trials | episodes spent | optimum at trial |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in results:
        batch = f"{r.config.batch}" + (f" (screen {r.config.screen_batch})" if r.config.screen_batch != r.config.batch
                                       else "")
        out.append(f"| `{r.name}` | {r.objective.describe()} | {r.config.recipe} | {batch} | {len(r.trials)} | "
                   f"{r.episodes} | {r.best_trial if r.best_trial is not None else 'none'} |")
    out += ["", f"## Table 3.1 equivalent: optimum per study (R on `{task}`)", "",
            "| study | ξ | x | y | z | l | R | 95 % CI | e (W/m) | p vs reference | thesis x, y, z, l | thesis R | "
            "thesis e | thesis p |", "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in data["table31"]:
        d = row["design"]
        R = row["R"].get(task)
        ci = row["ci95"].get(task)
        th = row.get("thesis")
        ths = (f"{th['x']:.3f}, {th['y']:.3f}, {th['z']:.3f}, {th['l']:.3f} | {th['R']:.3f} | {th['e']:.2f} | "
               f"{_fmt_p(th['p']) if th['p'] is not None else '-'}" if th else " | | | ")
        p = "(reference)" if row["study"] == reference.name else _fmt_p(row.get("p_vs_reference"))
        out.append(f"| `{row['study']}` | {row['xi']} | {d['x']:.3f} | {d['y']:.3f} | {d['z']:.3f} | {d['l']:.3f} | "
                   f"{_fmt(R)} | {_fmt(ci[0]) + ' … ' + _fmt(ci[1]) if ci else 'n/a'} | {_fmt(row['e'], 2)} | {p} | "
                   f"{ths} |")
    out += ["", f"## Table 3.2 equivalent: ±{PERTURBATION} m perturbations of the `{reference.name}` optimum", "",
            "\\* = outside the optimisation bounds (evaluated anyway).", "",
            "| change | x | y | z | l | R | p vs unperturbed | thesis R | thesis p | note |",
            "|---|---|---|---|---|---|---|---|---|---|"]
    for row in data["table32"]:
        x, y, z, l = row["design"]  # noqa: E741
        star = "" if row.get("in_bounds", False) else "*"
        p = _fmt_p(row.get("p")) if row["change"] != "none" else "(reference)"
        thesis_p = _fmt_p(row.get("thesis_p")) if row.get("thesis_p") is not None else "-"
        out.append(f"| {row['change']}{star} | {x:.3f} | {y:.3f} | {z:.3f} | {l:.3f} | {_fmt(row.get('R'))} | "
                   f"{p} | {row['thesis_R']:.3f} | {thesis_p} | {row.get('note', '')} |")
    uni = data["universal"]
    out += ["", "## Universal optimum", ""]
    if not uni["checked"]:
        out.append(f"Not checked: {uni['reason']}.")
    else:
        tasks = list(uni["matrix"])
        out += ["R of each task's optimum (columns) on each task (rows); p against the row task's own optimum.", "",
                "| task \\ optimum of | " + " | ".join(tasks) + " |", "|---" * (len(tasks) + 1) + "|"]
        for t in tasks:
            cells = []
            for o in tasks:
                c = uni["matrix"][t][o]
                cells.append(f"{c['R']:.3f}" + ("" if c["p_vs_own_optimum"] is None else
                                                f" (p {_fmt_p(c['p_vs_own_optimum'])})"))
            out.append(f"| {t} | " + " | ".join(cells) + " |")
        out += ["", "Optima: " + "; ".join(f"{t}: ({', '.join(f'{v:.3f}' for v in w)})"
                                           for t, w in uni["optima"].items()) + ".",
                "Verdict: " + ("**statistically the same robot**: no task's own optimum beats another task's "
                               "optimum on that task (all p ≥ 0.05)." if uni["same_robot"] else
                               "**not the same robot**: on at least one task its own optimum is significantly "
                               "better than another task's optimum.")]
    out += ["", "## Plots", "",
            "![objective vs trial](objective_vs_trial.png)", "",
            "![best design vs trial](best_design_vs_trial.png)", "",
            "![one-parameter slices](slices.png)", "",
            "![e(w) across the bounds](energy.png)", "",
            "## Compared with the thesis", ""]
    out += _findings(data, reference, task)
    return "\n".join(out) + "\n"


def _findings(data: dict[str, Any], reference: StudyResult, task: str) -> list[str]:
    """Plain statements on the thesis's claims, derived from the numbers above."""
    lines: list[str] = []
    rows = {r["change"]: r for r in data["table32"]}
    base_R = rows["none"]["R"]
    drops = {k: base_R - r["R"] for k, r in rows.items() if k != "none" and r.get("R") is not None}
    sig = {k for k, r in rows.items() if r.get("p") is not None and r["p"] < 0.05}
    tied = [k for k in drops if k not in sig]
    lines.append(f"- Plateau: {len(tied)} of {len(drops)} evaluated ±{PERTURBATION} m perturbations are statistically "
                 f"tied with the optimum (p ≥ 0.05){': ' + ', '.join(tied) if tied else ''}. The thesis found the "
                 "increases of x, y, z tied and every decrease significantly worse.")
    if drops:
        worst = max(drops, key=lambda k: drops[k])
        lines.append(f"- Largest drop: {worst} (R {base_R:.3f} → {rows[worst]['R']:.3f}). The thesis's largest "
                     "drop is −x (0.854 → 0.785); " + ("we agree." if worst == "-x" else "we disagree."))
    l_both = {"+l", "-l"} <= sig
    lines.append("- Is l the most finely tuned parameter (both directions significantly worse)? "
                 + ("Yes, as in the thesis." if l_both else
                    f"Not here: significant changes are {', '.join(sorted(sig)) or 'none'}."))
    uni = data["universal"]
    if uni["checked"]:
        lines.append("- Universal optimum: " + ("one robot serves all tasks, as the thesis found." if uni["same_robot"]
                                                else "the tasks want different robots, unlike the thesis."))
    rows31 = data["table31"]
    th = [r for r in rows31 if "thesis" in r and task in r["R"]]
    if th:
        lines.append("- Table 3.1: " + "; ".join(
            f"ξ={r['xi']}: R {r['R'][task]:.3f} vs thesis {r['thesis']['R']:.3f}, e {_fmt(r['e'], 2)} vs "
            f"{r['thesis']['e']:.2f} W/m" for r in th) + ".")
    return lines

