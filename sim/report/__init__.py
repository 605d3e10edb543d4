"""The optimisation report: thesis Tables 3.1 and 3.2 reproduced in our simulator, with plots.

``write_report`` reads finished studies and writes ``report.md``, ``report.json`` and PNG
plots into a folder. Every number in the tables comes from a fresh evaluation (seed
``seed``, which should differ from the studies' seed): the optimum of a search is the
design whose batch happened to score best, and re-using that batch would overstate it.
All designs are evaluated on the same episodes (common random numbers), so two designs are
compared with a paired t-test on per-episode final-state rewards.

Modules: :mod:`~tumblebot.sim.report.tables` (the numbers), :mod:`~tumblebot.sim.report.plots`
and :mod:`~tumblebot.sim.report.markdown`; this package's :func:`write_report` runs them.
"""

from __future__ import annotations

from pathlib import Path

from tumblebot.sim.evaluation.stats import paired_p
from tumblebot.sim.optimize import OptimizeError, open_storage, parse_policy_files
from tumblebot.sim.optimize.storage import redact_url
from tumblebot.sim.report.markdown import render_markdown
from tumblebot.sim.report.plots import draw_plots
from tumblebot.sim.report.tables import (
    THESIS_TABLE_31,
    THESIS_TABLE_31_P,
    THESIS_TABLE_32,
    Evaluated,
    Evaluator,
    StudyResult,
    build_table31,
    build_table32,
    check_policies,
    common_controller,
    load_results,
    one_parameter_slices,
    rebuild_pairs,
    reference_study,
    universal_check,
    would_i_still_build_it,
)
from tumblebot.sim.world.design import PARAMETERS
from tumblebot.sim.world.physics import PhysicsProfile

__all__ = ["THESIS_TABLE_31", "THESIS_TABLE_31_P", "THESIS_TABLE_32", "Evaluated", "StudyResult", "paired_p",
           "write_report"]


def _check_arguments(studies: list[str], episodes: int | None, slice_points: int, workers: int) -> None:
    """``report``'s numbers, checked before any study is read."""
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


def write_report(storage_url: str, studies: list[str], out_dir: Path, episodes: int | None = None,
                 workers: int = 1, seed: int = 1, slice_points: int = 7, progress: bool = True,
                 controller: str | None = None, physics: PhysicsProfile | None = None,
                 allow_servo_mismatch: bool = False, xis: tuple[float, ...] | None = None,
                 policies: list[str] | None = None) -> Path:
    """Evaluate and plot the studies; returns the path of ``report.md``.

    Every design is re-evaluated with one controller and one physics profile, so the tables
    compare like with like: ``controller`` (``"policy"``, ``goto`` or a gait) and ``physics`` default
    to what the studies used, which must then agree. A front study (``optimize --front``)
    stands for one row per ``ξ`` of ``xis`` (default: the ξ it was made for); ``xis`` is
    refused for other studies. ``policies`` (``--policy [TASK=]FILE``) replaces bundled
    policies; whichever policy re-evaluates a task must be the one its studies recorded."""
    _check_arguments(studies, episodes, slice_points, workers)
    storage = open_storage(storage_url, must_exist=True)
    results = [r for name in studies for r in load_results(storage, name, xis, strict=len(studies) == 1)]
    if xis is not None and not any(r.front_of is not None for r in results):
        raise OptimizeError("--xi reads optima from front studies (optimize --front); none of these studies is one")
    usable = [r for r in results if "best_design" in r.extra]
    if not usable:
        raise OptimizeError("none of the studies has a finished design yet; run tumblebot optimize first")
    if episodes is None:
        episodes = max(2, max(r.config.batch for r in results))
    all_tasks = sorted({t for r in results for t in r.tasks})
    reference = reference_study(usable)
    ref_task = reference.tasks[0]
    single = [r for r in usable if len(r.tasks) == 1]
    universal_tasks = sorted({r.tasks[0] for r in single})
    total = len(usable) + 9 + len(PARAMETERS) * slice_points + len(universal_tasks) ** 2
    out_dir.mkdir(parents=True, exist_ok=True)
    given = physics
    controller, physics = common_controller(results, controller, physics)
    pairs, missing = rebuild_pairs(usable, physics) if given is not None else ([], "")
    files = parse_policy_files(policies, all_tasks)
    ev = Evaluator(all_tasks, episodes, workers, seed, total, progress, controller, physics, allow_servo_mismatch,
                   files)
    rebuild: list[dict[str, object]] = []
    try:
        check_policies(results, controller, ev.policy_hashes)
        for r in usable:
            r.best = ev(r.extra["best_design"], r.tasks)
        assert reference.best is not None
        table31 = build_table31(usable, reference, ref_task)
        table32 = build_table32(ev, reference, ref_task)
        universal = universal_check(ev, single, universal_tasks)
        slices = one_parameter_slices(ev, reference, slice_points)
        if pairs:
            rebuild = would_i_still_build_it(pairs, ev, physics, allow_servo_mismatch)
    finally:
        ev.close()
    data = {"storage": redact_url(storage_url), "studies": [r.name for r in results], "episodes": episodes,
            "seed": seed,
            "reference_study": reference.name, "reference_task": ref_task,
            "study_episodes": {r.name: r.episodes for r in results},
            "controller": controller, "policies": ev.policy_hashes, "servo": physics.record(),
            "table31": table31, "table32": table32, "universal": universal, "slices": slices,
            "rebuild": rebuild, "rebuild_missing": missing}
    plots = draw_plots(results, reference, slices, out_dir)
    text = render_markdown(results, reference, ref_task, data, plots)
    (out_dir / "report.md").write_text(text)
    from tumblebot.sim.optimize import to_json

    (out_dir / "report.json").write_text(to_json(data) + "\n")
    return out_dir / "report.md"
