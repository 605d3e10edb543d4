"""Calibrate the benchmark's twin trial sets again with more spreads in the summary.

``tumblebot calibrate`` matches per-kind means of the logged steps and a few spreads
(``sim/calibration.py``, ``SPREADS``): until 2026-12-06 only the drives' distance, now the
spins' turn as well. The motor noise shows in how much steps differ from each other more
than in their means, so spreads may pin it down. This script fits each hidden world of
``benchmarks/bench_calibrate.py`` again from the identification trials that run left in
its ``--out`` folder, once per choice of spreads, and for each fit prints the parameters
(value, 90 % interval, identified or not) and the open-loop prediction of the world's
held-out pulse trials (the benchmark's two-sample Anderson–Darling test, against the true
profile's as the control).

``--swap`` asks the opposite question of the fit with the drives' spread alone (the
summary before 2026-12-06): which of its values moves the prediction. Each fitted value in
turn is set to the truth's, and the held-out trials are predicted again.

The simulations of every fit of a world are cached in its folder
(``.spreads-cache.jsonl``), so the fits share their first round and a second run costs
only the prediction.

Run from the repository root, after ``benchmarks/bench_calibrate.py`` (its twin stages):
``.venv/bin/python reports/calibration-statistics/spreads.py [--out runs/bench-calibrate]
[--variants drives,spins] [--swap]``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "benchmarks"))

from bench_calibrate import HIDDEN, replay_prediction  # noqa: E402

from tumblebot.host.calibrate import LoggedTrial, load_trials  # noqa: E402
from tumblebot.sim.calibration import PARAMETERS, SPREADS, Settings, Simulator, calibrate, profile_at  # noqa: E402
from tumblebot.sim.world.physics import THESIS, PhysicsProfile  # noqa: E402

#: the summaries compared: the spreads each holds besides the means
VARIANTS: dict[str, tuple[str, ...]] = {
    "drives": ("drive distance",),  # the summary before 2026-12-06
    "spins": SPREADS,  # the summary now: the drives' distance and the spins' turn
    "spin-start": ("drive distance", "spin turn", "start distance"),
    "turns": ("drive distance", "drive turn", "spin turn", "start distance"),
}


def fit(folder: Path, trials: list[LoggedTrial], spreads: tuple[str, ...]
        ) -> tuple[dict[str, dict[str, Any]], PhysicsProfile, float]:
    """The world's identification ``trials`` calibrated with ``spreads``: parameters, profile, misfit."""
    sim = Simulator([t.trace for t in trials], 2, folder / ".spreads-cache.jsonl")
    try:
        cal = calibrate([t.trace for t in trials], [t.track for t in trials], THESIS, "fitted", sim,
                        Settings(spreads=spreads))
    finally:
        sim.close()
    return cal.parameters, cal.profile, float(cal.fit["misfit_fitted"])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("runs/bench-calibrate"),
                        help="bench_calibrate.py's --out, with its twin trial sets (runs/bench-calibrate)")
    parser.add_argument("--variants", default=",".join(VARIANTS),
                        help=f"which summaries, comma-separated, of {', '.join(VARIANTS)} (all)")
    parser.add_argument("--swap", action="store_true",
                        help="also predict with each of the drives fit's values set to the truth's, one at a time")
    args = parser.parse_args()
    variants = [v for v in args.variants.split(",") if v]
    unknown = [v for v in variants if v not in VARIANTS]
    if unknown or not variants:
        parser.error(f"--variants: {', '.join(unknown) or 'none given'}; choose from {', '.join(VARIANTS)}")
    folders = [args.out / h["name"] for h in HIDDEN]
    missing = [str(f) for f in folders if not (f / "excite" / "index.json").is_file()
               or not (f / "holdout-pulse" / "index.json").is_file()]
    if missing:
        parser.error(f"no twin trial sets in {', '.join(missing)}: run benchmarks/bench_calibrate.py "
                     "--decision-trials 0 first")
    for folder in folders:
        truth = PhysicsProfile.load(str(folder / "world.json"))
        print(f"\n{truth.describe()}")
        trials = load_trials([folder / "excite"])
        for name in variants:
            parameters, profile, misfit = fit(folder, trials, VARIANTS[name])
            swapped = [profile_at(profile, {param.name: param.value(truth)}) for param in PARAMETERS] \
                if args.swap and name == "drives" else []
            # one reading of the held-out trials for every profile (each profile's replays
            # have their own seeds, so the order does not matter)
            logged, [(fitted_med, q_fit), (true_med, q_true), *swaps] = replay_prediction(
                folder / "holdout-pulse", (profile, truth, *swapped))
            print(f"  {name} ({', '.join(f'{s} sd' for s in VARIANTS[name])}): misfit {misfit:.2f}; held-out pulse "
                  f"trials, logged median {logged:.3f} m, fitted {fitted_med:.3f} m (p = {q_fit:.3f}), "
                  f"true profile {true_med:.3f} m (p = {q_true:.3f})")
            for param in PARAMETERS:
                e = parameters[param.name]
                verdict = "identified" if e["identifiable"] else "not identified"
                print(f"    {param.name:18s} true {param.value(truth):6.3g}  fitted {e['value']:6.3g}  "
                      f"90 % {e['low']:6.3g}..{e['high']:<6.3g}  {verdict}")
            for param, (med, q) in zip(PARAMETERS, swaps, strict=False):
                print(f"    with the true {param.name}: {med:.3f} m (p = {q:.3f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
