"""The universal-optimum check, ablated over the servo: is there one robot for every task?

Run from the repository root, after ``commands.sh`` has run its studies:
``.venv/bin/python reports/thesis-reproduction/universal_servo.py``

The thesis found one robot optimal for every task. Our ξ = 0 studies of the four tasks
(``commands.sh``, realistic servo, the bundled policies) do not: the navigation optimum is
a small body, the distance and incline optima are large ones. This script asks whether the
servo explains the difference. It takes each task's optimum (and the thesis's ξ = 0
robot) and scores every one of them on ``nav-flat``, ``distance-flat`` and ``incline``
under two servos: the realistic one (DC, the thesis's constants, 0.58 N·m, the default)
and a predecessor-like strong one (velocity control, 10 N·m).

No learned policy is used, since the bundled ones were trained under the realistic servo
only. Both controllers need no training, so they run under any servo:

* ``nav-flat``: ``goto``, the hand-written closed-loop controller (:mod:`tumblebot.sim.control.goto`).
* ``distance-flat`` and ``incline``: the scripted ``forward`` gait (both legs full forward
  every step), the best fixed gait on both tasks in the bundled policies' cards. (A
  closed-loop "face +x, then drive" controller was tried first: turning costs it more than
  it gains, and on the ramp it is far worse than ``forward``.)

Every cell is the same episodes (seed 1, common random numbers across bodies and servos).
Writes ``universal_servo.json`` and ``universal_servo.md`` beside this file.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from tumblebot.sim.evaluation.evaluate import Driver
from tumblebot.sim.evaluation.runner import EpisodeRunner
from tumblebot.sim.optimize import open_storage
from tumblebot.sim.report import paired_p
from tumblebot.sim.report.tables import load_results
from tumblebot.sim.world.design import THESIS_ROBOTS, Design
from tumblebot.sim.world.physics import PhysicsProfile

HERE = Path(__file__).resolve().parent
TASKS = ("nav-flat", "distance-flat", "incline")
STUDIES = {"nav-flat": "nav-flat-front", "nav-terrain": "nav-terrain-xi0", "distance-flat": "distance-flat-xi0",
           "incline": "incline-xi0"}
SERVOS = {"realistic (dc, 0.58 N·m)": PhysicsProfile(),
          "strong (velocity, 10 N·m)": PhysicsProfile.of("velocity", 10.0)}
#: the controller of each task (no training needed, so any servo)
CONTROLLERS = {"nav-flat": Driver.of_gait("goto"), "distance-flat": Driver.of_gait("forward"),
               "incline": Driver.of_gait("forward")}


def bodies(storage_url: str) -> dict[str, Design]:
    """Each task's ξ = 0 optimum (nav-flat's from its front study), and the thesis's ξ = 0 robot."""
    storage = open_storage(storage_url, must_exist=True)
    out = {}
    for task, study in STUDIES.items():
        result = load_results(storage, study, (0.0,) if task == "nav-flat" else None)[0]
        out[f"{task} optimum"] = result.extra["best_design"]
    out["thesis ξ = 0 robot"] = THESIS_ROBOTS["0"]
    return out


def _w(d: Design) -> str:
    return "(" + ", ".join(f"{v:.3f}" for v in d.as_tuple()) + ")"


def measure(args: argparse.Namespace) -> dict[str, Any]:
    designs = bodies(args.storage)
    cells: dict[str, dict[str, dict[str, list[float]]]] = {}
    started = time.monotonic()
    for servo_name, servo in SERVOS.items():
        with EpisodeRunner(CONTROLLERS, workers=args.workers, physics=servo) as runner:
            for task in TASKS:
                for body, d in designs.items():
                    R = runner.run(d, [task], 0, args.episodes, args.seed)[task].tolist()
                    cells.setdefault(servo_name, {}).setdefault(task, {})[body] = R
                    print(f"{servo_name:26} {task:14} {body:20} R {np.mean(R):.3f} "
                          f"({time.monotonic() - started:.0f} s)", flush=True)
    return {"episodes": args.episodes, "seed": args.seed, "seconds": round(time.monotonic() - started),
            "bodies": {b: d.as_tuple() for b, d in designs.items()}, "R": cells, "summary": summarise(cells)}


def summarise(cells: dict[str, dict[str, dict[str, list[float]]]]) -> dict[str, Any]:
    """Per servo and task: the best body, the bodies tied with it (paired p ≥ 0.05), the p-values."""
    summary: dict[str, Any] = {}
    for servo_name, by_task in cells.items():
        for task, by_body in by_task.items():
            R = {b: np.asarray(v) for b, v in by_body.items()}
            best = max(R, key=lambda b: float(np.mean(R[b])))
            p = {b: (None if b == best else paired_p(R[b], R[best])) for b in R}
            summary.setdefault(servo_name, {})[task] = {
                "best": best, "tied_with_best": [b for b in R if b == best or (p[b] or 0.0) >= 0.05], "p_vs_best": p}
    return summary


def render(data: dict[str, Any]) -> str:
    lines = ["# Universal optimum under two servos", "",
             f"Written by `universal_servo.py` ({data['episodes']} episodes per cell, seed {data['seed']}, the same "
             f"episodes in every cell; {data['seconds'] / 60:.0f} min on 2 cores). Controllers: `goto` on nav-flat, "
             "the scripted `forward` gait on distance-flat and incline; no learned policy. "
             "Each cell is mean final R; **bold** is the task's best body under that servo, and a † marks a "
             "body tied with it (paired t-test p ≥ 0.05).", ""]
    for servo_name, by_task in data["R"].items():
        lines += [f"## {servo_name} servo", "", "| body | design (x, y, z, l) | " + " | ".join(TASKS) + " |",
                  "|---|---|" + "---|" * len(TASKS)]
        for body, w in data["bodies"].items():
            cells = []
            for task in TASKS:
                s = data["summary"][servo_name][task]
                value = f"{np.mean(by_task[task][body]):.3f}"
                cells.append(f"**{value}**" if s["best"] == body else value + (" †" if body in s["tied_with_best"]
                                                                                 else ""))
            lines.append(f"| {body} | {_w(Design.from_sequence(w, allow_out_of_bounds=True))} | " + " | ".join(cells)
                         + " |")
        universal = [b for b in data["bodies"] if all(b in data["summary"][servo_name][t]["tied_with_best"]
                                                      for t in TASKS)]
        lines += ["", "Best or tied on every task: " + (", ".join(universal) if universal else "**none**") + ".", ""]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--storage", default="sqlite:///runs/thesis-new.db")
    ap.add_argument("--episodes", type=int, default=240)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    data = measure(args)
    (HERE / "universal_servo.json").write_text(json.dumps(data, indent=1) + "\n")
    (HERE / "universal_servo.md").write_text(render(data))
    print(render(data))


if __name__ == "__main__":
    main()
