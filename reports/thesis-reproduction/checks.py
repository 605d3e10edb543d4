"""The reproduction's two robustness checks, after ``commands.sh`` has run its studies.

Run from the repository root: ``.venv/bin/python reports/thesis-reproduction/checks.py``

* **Driver robustness.** The per-ξ optima of the front study searched with the bundled
  policy and of the same front study searched with ``goto`` (the hand-written controller),
  each evaluated under *both* controllers on the same 240 fresh episodes (seed 1). Where the
  two searches chose different bodies, the paired tests say whether the choice matters
  under either controller.
* **Retrain check.** The bundled policy fine-tuned with PPO on one body at a time (the
  front's ξ = 3 optimum and the thesis's ξ = 0 and ξ = 3 robots), the same budget for each
  (``--steps``), then each body evaluated with its own retrained policy. Published co-design
  work finds that retraining after the design is chosen can change the answer: does the
  ranking of the three bodies at ξ = 0 and ξ = 3 hold?

Writes ``checks.json`` and ``checks.md`` beside this file.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from tumblebot.sim.control.policy import bundled_policy
from tumblebot.sim.evaluation.evaluate import Driver
from tumblebot.sim.evaluation.runner import EpisodeRunner
from tumblebot.sim.optimize import front_optima, load_study, open_storage
from tumblebot.sim.report import paired_p
from tumblebot.sim.world.design import THESIS_ROBOTS, Design
from tumblebot.sim.world.power import energy_per_metre

HERE = Path(__file__).resolve().parent
XIS = (0.0, 1.0, 3.0, math.inf)
TASK = "nav-flat"
#: the fine-tune's PPO settings (training/configs/nav-finetune.json), with the body fixed
FINETUNE = json.loads((HERE.parents[1] / "training" / "configs" / "nav-finetune.json").read_text())


def objective(R: np.ndarray, design: Design, xi: float) -> np.ndarray:
    e = energy_per_metre(design)
    return np.full(len(R), -e) if math.isinf(xi) else np.asarray(R) / (e + 1.0) ** xi


def _label(xi: float) -> str:
    return "inf" if math.isinf(xi) else f"{xi:g}"


def _w(d: Design) -> str:
    return "(" + ", ".join(f"{v:.3f}" for v in d.as_tuple()) + ")"


def robustness(args: argparse.Namespace) -> dict[str, Any]:
    storage = open_storage(args.storage, must_exist=True)
    optima = {name: front_optima(load_study(storage, study), XIS)
              for name, study in (("policy", args.policy_study), ("goto", args.goto_study))}
    runner = EpisodeRunner({"policy": bundled_policy(TASK), "goto": Driver.of_gait("goto")}, workers=args.workers,
                           task=TASK)
    cache: dict[tuple[str, tuple[float, ...]], np.ndarray] = {}

    def R(controller: str, d: Design) -> np.ndarray:
        key = (controller, d.as_tuple())
        if key not in cache:
            cache[key] = runner.run(d, [controller], 0, args.episodes, args.seed)[controller]
        return cache[key]

    rows = []
    try:
        for xi in XIS:
            a, b = optima["policy"][xi].design, optima["goto"][xi].design
            row: dict[str, Any] = {"xi": _label(xi), "policy_optimum": a.as_tuple(), "goto_optimum": b.as_tuple(),
                                   "same_body": bool(np.allclose(a.as_tuple(), b.as_tuple()))}
            for controller in ("policy", "goto"):
                fa, fb = objective(R(controller, a), a, xi), objective(R(controller, b), b, xi)
                row[f"under_{controller}"] = {
                    "policy_optimum": float(np.mean(fa)), "goto_optimum": float(np.mean(fb)),
                    "R_policy_optimum": float(np.mean(R(controller, a))),
                    "R_goto_optimum": float(np.mean(R(controller, b))),
                    "p": None if math.isinf(xi) else paired_p(fa, fb)}
            rows.append(row)
            print(f"robustness ξ = {_label(xi)}: policy optimum {_w(a)}, goto optimum {_w(b)}", flush=True)
    finally:
        runner.close()
    return {"episodes": args.episodes, "seed": args.seed, "rows": rows}


def retrain(args: argparse.Namespace) -> dict[str, Any]:
    storage = open_storage(args.storage, must_exist=True)
    chosen = front_optima(load_study(storage, args.policy_study), (3.0,))[3.0].design
    bodies = {"front ξ = 3 optimum": ("front-xi3", chosen), "thesis ξ = 0 robot": ("thesis-xi0", THESIS_ROBOTS["0"]),
              "thesis ξ = 3 robot": ("thesis-xi3", THESIS_ROBOTS["3"])}
    out: dict[str, Any] = {"steps": args.steps, "init_from": args.init_from, "config": FINETUNE,
                           "episodes": args.episodes, "seed": args.seed, "bodies": {}}
    tb = [sys.executable, "-m", "tumblebot.cli"]
    for name, (slug, design) in bodies.items():
        run_dir = Path(args.runs) / f"retrain-{slug}"
        policy = run_dir / "policy.onnx"
        if not policy.is_file():
            config = run_dir.with_suffix(".json")
            config.parent.mkdir(parents=True, exist_ok=True)
            config.write_text(json.dumps({**FINETUNE, "design": list(design.as_tuple())}) + "\n")
            started = time.monotonic()
            train = [*tb, "train", "--task", TASK, "--init-from", args.init_from, "--config", str(config),
                     "--steps", str(args.steps), "--run-dir", str(run_dir)]
            if (run_dir / "latest.zip").exists():
                train = [*tb, "train", "--resume", "--run-dir", str(run_dir)]
            subprocess.run(train, check=True, stdin=subprocess.DEVNULL)
            subprocess.run([*tb, "export", str(run_dir), "-o", str(policy), "--eval-episodes", "0"], check=True,
                           stdin=subprocess.DEVNULL)
            print(f"retrained on {name} {_w(design)} in {time.monotonic() - started:.0f} s", flush=True)
        with EpisodeRunner({"bundled": bundled_policy(TASK), "retrained": policy}, workers=args.workers,
                           task=TASK) as runner:
            results = runner.run(design, ["bundled", "retrained"], 0, args.episodes, args.seed)
        out["bodies"][name] = {
            "design": design.as_tuple(), "e": energy_per_metre(design),
            "R_bundled": float(np.mean(results["bundled"])), "R_retrained": float(np.mean(results["retrained"])),
            "p_retrained_vs_bundled": paired_p(results["retrained"], results["bundled"]),
            "per_episode_retrained": results["retrained"].tolist(), "per_episode_bundled": results["bundled"].tolist()}
        print(f"{name}: R {np.mean(results['bundled']):.3f} (bundled) → {np.mean(results['retrained']):.3f} "
              "(retrained)", flush=True)
    for policy_kind in ("bundled", "retrained"):
        for xi in (0.0, 3.0):
            ranked = sorted(out["bodies"], key=lambda n: -float(np.mean(objective(
                np.array(out["bodies"][n][f"per_episode_{policy_kind}"]), Design(*out["bodies"][n]["design"]), xi))))
            out[f"ranking_{policy_kind}_xi{xi:g}"] = ranked
    return out


def render(data: dict[str, Any]) -> str:
    lines = ["# Robustness checks of the reproduction", "",
             f"Written by `checks.py` ({data['date']}). Every R is on {data['robustness']['episodes']} fresh "
             f"episodes (seed {data['robustness']['seed']}), the same for every design; p: paired t-test.", "",
             "## Driver robustness: the optimum under the policy against the optimum under goto", "",
             "| ξ | policy's optimum | goto's optimum | same body | under the policy: objective (R) of each, p "
             "| under goto: objective (R) of each, p |", "|---|---|---|---|---|---|"]
    for row in data["robustness"]["rows"]:
        cells = []
        for c in ("policy", "goto"):
            u = row[f"under_{c}"]
            p = "n/a" if u["p"] is None else f"{u['p']:.2g}"
            cells.append(f"{u['policy_optimum']:.4g} ({u['R_policy_optimum']:.3f}) vs {u['goto_optimum']:.4g} "
                         f"({u['R_goto_optimum']:.3f}), p {p}")
        lines.append(f"| {row['xi']} | {_w(Design(*row['policy_optimum']))} | {_w(Design(*row['goto_optimum']))} | "
                     f"{'yes' if row['same_body'] else 'no'} | {cells[0]} | {cells[1]} |")
    r = data["retrain"]
    if r is None:
        return "\n".join([*lines, "", "## Retrain check", "", "Not run (`--skip-retrain`)."]) + "\n"
    lines += ["", "## Retrain check: each body with a policy fine-tuned on it", "",
              f"PPO from `{r['init_from']}`, {r['steps']} steps per body, the fine-tune's settings "
              f"(`training/configs/nav-finetune.json`) with the body fixed.", "",
              "| body | design | e (W/m) | R, bundled policy | R, retrained | p |", "|---|---|---|---|---|---|"]
    for name, b in r["bodies"].items():
        p = "n/a" if b["p_retrained_vs_bundled"] is None else f"{b['p_retrained_vs_bundled']:.2g}"
        lines.append(f"| {name} | {_w(Design(*b['design']))} | {b['e']:.2f} | {b['R_bundled']:.3f} | "
                     f"{b['R_retrained']:.3f} | {p} |")
    lines += [""]
    for xi in ("0", "3"):
        same = r[f"ranking_bundled_xi{xi}"] == r[f"ranking_retrained_xi{xi}"]
        lines.append(f"- Ranking at ξ = {xi}: bundled policy {' > '.join(r[f'ranking_bundled_xi{xi}'])}; "
                     f"retrained {' > '.join(r[f'ranking_retrained_xi{xi}'])}: "
                     + ("**the ranking holds**." if same else "**the ranking changes**."))
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--storage", default="sqlite:///runs/thesis-new.db")
    ap.add_argument("--policy-study", default="nav-flat-front")
    ap.add_argument("--goto-study", default="nav-flat-front-goto")
    ap.add_argument("--episodes", type=int, default=240)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--steps", type=int, default=30_000, help="PPO steps of each body's fine-tune")
    ap.add_argument("--init-from", default="training/checkpoints/bc-nav-flat/latest.zip")
    ap.add_argument("--runs", default="runs")
    ap.add_argument("--skip-retrain", action="store_true", help="only the controller-robustness check")
    args = ap.parse_args()
    data = {"date": time.strftime("%Y-%m-%d"), "robustness": robustness(args),
            "retrain": None if args.skip_retrain else retrain(args)}
    (HERE / "checks.json").write_text(json.dumps(data, indent=2) + "\n")
    (HERE / "checks.md").write_text(render(data))
    print(f"wrote {HERE / 'checks.md'}")


if __name__ == "__main__":
    main()
