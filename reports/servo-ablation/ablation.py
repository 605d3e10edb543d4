"""Servo-torque ablation: which bodies can a motor actually drive? (issue: servo torque)

For the thesis's four robots and for the optima of studies run under each servo, the mean
final R on ``nav-flat`` under the realistic servo (DC line from the thesis's motor
constants, 0.58 N·m stall) and under stronger ones, with two controllers: ``goto`` (the
hand-written closed-loop controller, needs no training, so it runs under any servo) and
the bundled ``nav-flat`` policy (trained under the default servo, so it is reported only
there). Same episodes for every cell (common random numbers, seed 0).

Run from the repository root: ``.venv/bin/python reports/servo-ablation/ablation.py``
(``--episodes``, ``--workers``; ``--studies DB`` adds the optima of the servo studies in
``commands.sh``). Writes ``results.json`` and ``table.md`` beside this file.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

from tumblebot.sim.control.policy import bundled_policy, sha256_of
from tumblebot.sim.evaluation.evaluate import Driver, evaluate
from tumblebot.sim.world.constants import STALL_TORQUE
from tumblebot.sim.world.design import THESIS_ROBOTS, Design
from tumblebot.sim.world.physics import PhysicsProfile

HERE = Path(__file__).resolve().parent
SERVOS = {
    "dc 0.58 N·m (default)": PhysicsProfile.of("dc", STALL_TORQUE),
    "velocity 0.58 N·m": PhysicsProfile.of("velocity", STALL_TORQUE),
    "velocity 2 N·m": PhysicsProfile.of("velocity", 2.0),
    "velocity 10 N·m (predecessor-like)": PhysicsProfile.of("velocity", 10.0),
}


def study_optima(storage: str) -> dict[str, Design]:
    from tumblebot.sim.optimize import best_candidate, load_study, open_storage

    st = open_storage(storage, must_exist=True)
    out = {}
    for name in ("servo-dc-xi0", "servo-strong-xi0"):
        best = best_candidate(load_study(st, name))
        if best is not None:
            out[f"optimum of study {name}"] = best.design
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=240)
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--studies", default=None, help="storage URL of the servo studies (commands.sh)")
    args = parser.parse_args()
    designs = {f"thesis ξ = {xi} robot": w for xi, w in THESIS_ROBOTS.items()}
    if args.studies:
        designs.update(study_optima(args.studies))
    policy = Driver("onnx", str(bundled_policy("nav-flat")))
    rows: list[dict[str, Any]] = []
    started = time.time()
    for label, w in designs.items():
        row: dict[str, Any] = {"design": label, "w": list(w.as_tuple()), "goto": {}, "policy": {}}
        for name, servo in SERVOS.items():
            r = evaluate("nav-flat", w, Driver.of_gait("goto"), args.episodes, 0, args.workers, physics=servo)
            row["goto"][name] = {"mean_R": r.mean_R, "ci95": list(r.ci95)}
            print(f"{label:<40} goto   {name:<36} {r.mean_R:.3f}", flush=True)
        r = evaluate("nav-flat", w, policy, args.episodes, 0, args.workers)
        row["policy"]["dc 0.58 N·m (default)"] = {"mean_R": r.mean_R, "ci95": list(r.ci95)}
        print(f"{label:<40} policy {'dc 0.58 N·m (default)':<36} {r.mean_R:.3f}", flush=True)
        rows.append(row)
    meta = {"date": time.strftime("%Y-%m-%d"), "episodes": args.episodes, "seed": 0, "task": "nav-flat",
            "wall_seconds": time.time() - started, "policy_sha256": sha256_of(Path(policy.name))}
    (HERE / "results.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1) + "\n")
    header = " | ".join(f"goto, {n}" for n in SERVOS)
    lines = [f"| design (x, y, z, l) | {header} | nav-flat policy, default servo |",
             "|---|" + "---|" * (len(SERVOS) + 1)]
    for row in rows:
        cells = [f"{row['goto'][n]['mean_R']:.3f}" for n in SERVOS]
        cells.append(f"{row['policy']['dc 0.58 N·m (default)']['mean_R']:.3f}")
        shown = ", ".join(f"{v:.3f}" for v in row["w"])
        lines.append(f"| {row['design']} ({shown}) | " + " | ".join(cells) + " |")
    (HERE / "table.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
