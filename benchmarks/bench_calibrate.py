"""Calibration against hidden worlds, through the digital twin.

Run: ``.venv/bin/python benchmarks/bench_calibrate.py [--trials 15] [--holdout 10] [--out DIR]``

For each hidden physics profile (far from ``thesis``: the free speed, the stall torque, the
floor and the radio all differ), the digital twin is the lab: its world runs the profile,
and the host, the agent and the calibration are not told it.

1. **Recovery**: the identification run (``twin run --policy excite``, ``--trials`` trials
   on 5 start points), then ``tumblebot calibrate``. Every parameter it calls identifiable
   must have its true value inside its 90 % interval, the free speed within 10 %, and an
   interval no wider than ±25 %; one it calls not identifiable says so.
2. **Prediction**: ``--holdout`` ordinary trials of the bundled policy through the twin,
   not used by the fit. From each trial's start, 16 pure-simulation episodes under the
   fitted profile and 16 under ``thesis`` (``tumblebot twin check``'s simulation); the
   logged final distances are compared with each by a two-sample Anderson–Darling test
   (the fitted profile should not be told apart, ``thesis`` should).
3. **Cost**: the calibration's wall time on this machine.

It takes about 15 minutes per profile on 2 cores (the twin runs in real time). The
figures, with date and machine, go into ``docs/physics.md``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from tumblebot.sim.physics import THESIS, PhysicsProfile

HIDDEN: tuple[dict[str, Any], ...] = (
    {"name": "fast-weak-slippery", "free_speed": 4.5, "stall_torque": 0.4, "friction": 0.55,
     "latency": [0.03, 0.07]},
    {"name": "slow-strong-grippy", "free_speed": 2.9, "stall_torque": 1.3, "friction": 1.05},
    {"name": "fast-strong", "free_speed": 4.2, "stall_torque": 1.0, "friction": 0.7, "motor_speed_sigma": 0.5},
)


def tb(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "tumblebot.cli", *args], capture_output=True, text=True,
                          check=False, stdin=subprocess.DEVNULL, env={**os.environ, "PYTHONUNBUFFERED": "1"})


def twin(out: Path, world: Path, policy: str, trials: int, seed: int) -> None:
    if (out / "index.json").is_file() and len(json.loads((out / "index.json").read_text())["trials"]) >= trials:
        return  # done in an earlier run of the benchmark
    run = tb("twin", "run", "--out", str(out), "--policy", policy, "--points", "5", "--per-point",
             str(max(1, trials // 5)), "--world-physics", str(world), "--seed", str(seed))
    if run.returncode != 0:
        raise SystemExit(f"twin run failed:\n{run.stdout[-2000:]}\n{run.stderr[-2000:]}")


def prediction(holdout: Path, profile: PhysicsProfile) -> tuple[float, float]:
    """Anderson–Darling p of the logged final distances against pure simulation under ``profile``."""
    from scipy.stats import anderson_ksamp

    from tumblebot.host.trials import load_index
    from tumblebot.host.twin import simulate_starts

    logged = np.array([t["final_error"] for t in load_index(holdout)["trials"]])
    simulated = np.concatenate(simulate_starts(holdout, physics=profile)["per_trial"])
    test = anderson_ksamp([logged, simulated], method=None)
    return float(np.median(simulated)), float(np.clip(test.pvalue, 0.001, 0.25))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trials", type=int, default=15, help="identification trials per hidden world (15)")
    ap.add_argument("--holdout", type=int, default=10, help="held-out policy trials per hidden world (10)")
    ap.add_argument("--out", type=Path, default=Path("runs/bench-calibrate"), help="where the trial sets go")
    ap.add_argument("--only", type=int, help="run only this hidden world (0, 1, 2)")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    print(f"bench_calibrate {time.strftime('%Y-%m-%d')} on {platform.node()} ({os.cpu_count()} cores, "
          f"{platform.processor() or platform.machine()}): {args.trials} identification trials and {args.holdout} "
          "held-out policy trials per hidden world, through the twin")
    rows = []
    for k, hidden in enumerate(HIDDEN):
        if args.only is not None and k != args.only:
            continue
        truth = PhysicsProfile.from_json(hidden)
        folder = args.out / hidden["name"]
        folder.mkdir(exist_ok=True)
        world = folder / "world.json"
        truth.write(world)
        twin(folder / "excite", world, "excite", args.trials, seed=10 + k)
        start = time.monotonic()
        fitted_path = folder / "fitted.json"
        cal = tb("calibrate", str(folder / "excite"), "-o", str(fitted_path), "--json")
        seconds = time.monotonic() - start
        if cal.returncode != 0:
            raise SystemExit(f"calibrate failed:\n{cal.stderr[-3000:]}")
        result = json.loads(cal.stdout)
        fitted = PhysicsProfile.load(str(fitted_path))
        print(f"\n{truth.describe()}\n  calibrated from {args.trials} twin trials in {seconds / 60:.1f} min")
        ok = True
        for name, p in result["parameters"].items():
            true = getattr(truth, name) if name != "latency" else 0.5 * sum(truth.latency)
            inside = p["low"] <= true <= p["high"]
            verdict = ("identified, truth inside" if inside else "identified, TRUTH OUTSIDE") if p["identifiable"] \
                else ("not identifiable (prior kept)" if p["kept_prior"] else "not identifiable (uncertain)")
            ok &= inside or not p["identifiable"]
            print(f"  {name:18s} true {true:7.3g}  fitted {p['value']:7.3g}  90 % {p['low']:7.3g}..{p['high']:<7.3g} "
                  f" {verdict}")
        speed = result["parameters"]["free_speed"]
        speed_ok = speed["identifiable"] and abs(speed["value"] - truth.free_speed) <= 0.1 * truth.free_speed
        row: dict[str, Any] = {"world": hidden["name"], "recovery": bool(ok and speed_ok), "minutes": seconds / 60}
        if args.holdout > 0:
            twin(folder / "holdout", world, "nav-flat", args.holdout, seed=100 + k)
            logged = np.array([t["final_error"] for t in json.loads((folder / "holdout" / "index.json").read_text())
                               ["trials"]])
            med_fit, p_fit = prediction(folder / "holdout", fitted)
            med_thesis, p_thesis = prediction(folder / "holdout", THESIS)
            print(f"  held-out final distance: logged median {np.median(logged):.3f} m; simulated under the fitted "
                  f"profile {med_fit:.3f} m (p = {p_fit:.3f}), under thesis {med_thesis:.3f} m (p = {p_thesis:.3f})")
            row.update(p_fitted=p_fit, p_thesis=p_thesis)
        rows.append(row)
    print("\nworld                 recovery  minutes  p(fitted)  p(thesis)")
    for r in rows:
        print(f"{r['world']:21s} {'yes' if r['recovery'] else 'NO':8s} {r['minutes']:7.1f}  "
              f"{r.get('p_fitted', float('nan')):9.3f}  {r.get('p_thesis', float('nan')):9.3f}")
    return 0 if all(r["recovery"] for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
