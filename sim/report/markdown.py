"""The report as Markdown, and the findings it states."""

from __future__ import annotations

import math
from typing import Any

from tumblebot.sim.report.tables import CONTROLLER_LABEL, PERTURBATION, StudyResult


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



# ------------------------------------------------------------------------------- text
def render_markdown(results: list[StudyResult], reference: StudyResult, task: str, data: dict[str, Any],
              plots: dict[str, str]) -> str:
    E = data["episodes"]
    out: list[str] = [
        "# Design optimisation report", "",
        f"Storage `{data['storage']}`; studies {', '.join(f'`{r.name}`' for r in results)}.",
        f"Every R below is a fresh evaluation: {E} episodes per design and task, seed {data['seed']}, the same "
        "episodes for every design (common random numbers). p-values are two-sided paired t-tests on "
        "per-episode final-state R; p < 0.05 in bold.",
        f"Driver: {CONTROLLER_LABEL.get(data['controller'], data['controller'])}"
        + "".join(f"; {task} policy SHA-256 `{digest[:12]}…`" for task, digest in data.get("policies", {}).items())
        + f"; servo: {data['servo']['motor_model']} model, stall torque {data['servo']['stall_torque']:.3g} N·m.", "",
        "## Studies", "",
        "| study | objective | recipe | batch | feasible trials | episodes spent | optimum at trial |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in results:
        batch = f"{r.config.batch}" + (f" (screen {r.config.screen_batch})" if r.config.screen_batch != r.config.batch
                                       else "")
        spent = f"{r.episodes}" if r.front_of is None else f"{r.episodes} (the front study's, shared)"
        described = r.objective.describe() + ("" if r.front_of is None else f", read from front study `{r.front_of}`")
        out.append(f"| `{r.name}` | {described} | {r.config.recipe} | {batch} | {len(r.trials)} | "
                   f"{spent} | {r.best_trial if r.best_trial is not None else 'none'} |")
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
            "\\* = outside the optimisation bounds (evaluated anyway). The thesis columns are the thesis's own "
            "Table 3.2: the same perturbations of *its* ξ = 0 robot (0.293, 0.117, 0.158, 0.218), not of this "
            "optimum; compare the direction and size of each change, not the values.", "",
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
            *(["![the front: R against e(w)](front.png)", ""] if "front" in plots else []),
            "## Compared with the thesis", ""]
    out += _findings(data, reference, task)
    out += _rebuild(data)
    return "\n".join(out) + "\n"


def _rebuild(data: dict[str, Any]) -> list[str]:
    """"Would I still build it?": the thesis-world optimum against the one found for the profile."""
    rows, missing = data.get("rebuild") or [], data.get("rebuild_missing") or ""
    if not rows and not missing:
        return []
    name = data["servo"].get("name", "the profile")
    out = ["", f"## Would I still build it? (under `{name}`)", ""]
    if missing:
        return [*out, f"Not answered: {missing}."]
    out += [f"Each optimum scored on the same {data['episodes']} episodes per task under both worlds (mean "
            "per-episode objective; paired t-test).", "",
            "| objective | world | thesis-world optimum | optimum for the profile | p |", "|---|---|---|---|---|"]
    for r in rows:
        for world, label in (("physics", f"`{name}`"), ("thesis", "thesis")):
            w = r[world]
            out.append(f"| {r['objective']} | {label} | {w['thesis_optimum']:.3f} | {w['physics_optimum']:.3f} | "
                       f"{_fmt_p(w['p'])} |")
    out.append("")
    for r in rows:
        t, m = r["thesis_optimum"], r["physics_optimum"]
        out.append(f"- {r['objective']}: thesis-world optimum (`{r['thesis_study']}`) x, y, z, l = "
                   f"{t['x']:.3f}, {t['y']:.3f}, {t['z']:.3f}, {t['l']:.3f}; optimum for the profile "
                   f"(`{r['physics_study']}`) {m['x']:.3f}, {m['y']:.3f}, {m['z']:.3f}, {m['l']:.3f}. "
                   f"**{r['verdict']}**")
    return out


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
