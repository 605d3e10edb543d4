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
   not used by the fit, compared with simulation under the fitted profile and under
   ``thesis`` by two-sample Anderson–Darling tests (the fitted profile should not be told
   apart, ``thesis`` should): closed loop, the final distances to the setpoint against 16
   pure-simulation episodes of the policy from each trial's start (``tumblebot twin
   check``'s simulation); open loop, on ``--holdout-open`` trials of a scripted gait
   (``--holdout-gait``, default ``pulse``: a drive step, then a stopped one; scripted, so
   open loop in the twin as well), the distance each covered from start to end against 8
   replays of its logged commands. (Replaying a closed-loop trial open loop is not the same
   experiment: under the true profile itself its distances differ, p = 0.006 in one
   measured world.) The policy closes the loop and reaches the setpoint under any servo,
   so its final distances say little about the simulator; a scripted run's final distance
   scales with how far each drive step goes, which the servo sets. The control, in both: the
   simulation under the true profile itself, which must not be told apart either. The twin
   runs in real time, so on a loaded machine its chain's delays grow and its trials drift
   from any pure replay (run the benchmark on an idle machine).
3. **Decision** (``--decision-trials N``, ``--decision-seeds K``): ``optimize --physics
   FITTED`` and ``optimize --physics TRUE`` at the same budget with each of K optimiser seeds
   (nav-flat, ξ = 3, the efficient recipe, ``goto`` driving the episodes: the bundled
   policies were trained under ``thesis`` only), then every optimum evaluated under the true
   profile on the same 480 episodes; with each seed the fitted profile's optimum must tie the
   true one's (paired t-test on the per-episode objective, p > 0.05) or beat it. The
   yardstick beside it: how often two studies under the true profile itself (neighbouring
   seeds) tie each other, which is as often as any profile can be expected to. Where the
   fitted profile's optimum is worse, both optima are scored under the fitted profile as
   well, on the same episodes: if it ranks them as the truth does, its study missed a
   design it would have rated higher (the search's miss); if it ties them or ranks them the
   other way, the fit misled it.
4. **Cost**: the calibration's wall time on this machine.

Without the decision stage it takes about 20 minutes per profile on 2 cores (the twin
runs its 40 trials in real time; the calibration about 5 minutes); the decision stage
about 4 minutes per 100 trials and seed (its two studies), so about 12 more per profile
with the defaults (100 trials, 3 seeds, the budget of the committed results). Every stage
keeps its results in ``--out`` and a second run reuses them; the summary, with each world's
fitted profile and every decision's optima, goes to ``--json``
(``benchmarks/results/calibrate.json``). The figures, with date and machine, go into
``docs/physics.md`` (the latest run) and ``docs/research/calibration-runs.md`` (every run).

``--decision-from SUMMARY`` measures the decision stage alone on the fitted profiles an
earlier run left in its summary (after a change to the optimiser, say): no twin and no
calibration, the other stages' results carried over and dated as theirs
(``calibration_stages``), the studies in ``--out``. ``--decision-batch`` sets the studies'
full batch.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from tumblebot import jsonio
from tumblebot.sim.control.gaits import GAITS
from tumblebot.sim.world.physics import THESIS, PhysicsProfile

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


def ad_p(a: np.ndarray, b: np.ndarray) -> float:
    """Two-sample Anderson–Darling p (SciPy's table: reported within 0.001..0.25)."""
    import warnings

    from scipy.stats import anderson_ksamp

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return float(np.clip(anderson_ksamp([a, b]).pvalue, 0.001, 0.25))


def prediction(holdout: Path, profile: PhysicsProfile) -> tuple[float, float, float]:
    """Closed loop: the logged final distances to the setpoint against pure simulation of
    the policy from the same starts under ``profile``: (logged median, simulated median, p)."""
    from tumblebot.host.trial_sets import load_index
    from tumblebot.host.twin import simulate_starts

    logged = np.array([t["final_error"] for t in load_index(holdout)["trials"]])
    simulated = np.concatenate(simulate_starts(holdout, physics=profile)["per_trial"])
    return float(np.median(logged)), float(np.median(simulated)), ad_p(logged, simulated)


def replay_prediction(holdout: Path, profiles: Sequence[PhysicsProfile], seeds: int = 8
                      ) -> tuple[float, list[tuple[float, float]]]:
    """Open loop: each held-out trial's logged commands replayed from its logged start under
    each of ``profiles`` (``seeds`` times); the distance from start to end of the logged trials
    against the replays': (logged median, [(simulated median, p) per profile]). The trials
    are read once."""
    from tumblebot.host.calibrate import load_trials
    from tumblebot.sim.calibration import replay

    trials = load_trials([holdout])
    logged = np.array([np.hypot(t.track.x[-1] - t.track.x[0], t.track.y[-1] - t.track.y[0]) for t in trials])
    out = []
    for profile in profiles:
        env = profile.make_env("nav-flat")
        try:
            simulated = np.array([np.hypot(tk.x[-1] - tk.x[0], tk.y[-1] - tk.y[0])
                                  for j, t in enumerate(trials) for s in range(seeds)
                                  for tk in [replay(env, t.trace, 7_000_000 + 100 * j + s)]])
        finally:
            env.close()
        out.append((float(np.median(simulated)), ad_p(logged, simulated)))
    return float(np.median(logged)), out


def calibrate(folder: Path) -> tuple[dict[str, Any], float]:
    """``tumblebot calibrate`` on the world's identification runs (or its earlier result)."""
    record = folder / "calibration.json"
    if record.is_file():  # calibrated by an earlier run of the benchmark
        kept = json.loads(record.read_text())
        return kept["result"], float(kept["seconds"])
    start = time.monotonic()
    cal = tb("calibrate", str(folder / "excite"), "-o", str(folder / "fitted.json"), "--json")
    seconds = time.monotonic() - start
    if cal.returncode != 0:
        raise SystemExit(f"calibrate failed:\n{cal.stderr[-3000:]}")
    result: dict[str, Any] = json.loads(cal.stdout)
    record.write_text(json.dumps({"result": result, "seconds": seconds}) + "\n")
    return result, seconds


def open_loop(holdout: Path, fitted: PhysicsProfile, truth: PhysicsProfile, gait: str) -> tuple[float, float, float]:
    """Open-loop prediction of held-out scripted trials under the fitted profile and ``thesis``,
    and, the control, under the true profile: (p fitted, p thesis, p true). The twin runs in
    real time, so a loaded machine delays its chain and its trials drift from any pure
    replay; the control shows whether the instrument is sound in this run."""
    log_med, [(open_fit, q_fit), (open_thesis, q_thesis), (open_true, q_true)] = \
        replay_prediction(holdout, (fitted, THESIS, truth))
    print(f"  held-out {gait} trials, open loop (their commands replayed): distance from start to end, "
          f"logged median {log_med:.3f} m; simulated under the fitted profile {open_fit:.3f} m (p = {q_fit:.3f}), "
          f"under thesis {open_thesis:.3f} m (p = {q_thesis:.3f}); control, under the true profile "
          f"{open_true:.3f} m (p = {q_true:.3f})")
    return q_fit, q_thesis, q_true


#: The decision studies' full batch by default; studies of another batch are named apart.
DECISION_BATCH = 48


def optimum(folder: Path, profile: Path, study: str, trials: int, seed: int = 0, batch: int = DECISION_BATCH
            ) -> tuple[float, ...]:
    """The design ``optimize --physics PROFILE --seed SEED`` finds (resumed if the study exists)."""
    summary = folder / f"optimum-{study}.json"  # not the profile files beside it
    run = tb("optimize", "--tasks", "nav-flat", "--xi", "3", "--gait", "goto", "--recipe", "efficient",
             "--trials", str(trials), "--batch", str(batch), "--physics", str(profile), "--seed", str(seed),
             "--workers", "2", "--storage", f"sqlite:///{folder / 'decision.db'}", "--study", study, "--quiet",
             "--json", str(summary))
    if run.returncode != 0:
        raise SystemExit(f"optimize failed:\n{run.stderr[-3000:]}")
    best = json.loads(summary.read_text())["best"]
    return tuple(float(best["design"][k]) for k in ("x", "y", "z", "l"))


def objectives(design: tuple[float, ...], profile: Path, folder: Path, episodes: int, tag: str = "") -> np.ndarray:
    """Per-episode objective R/(e+1)^3 of ``design`` under ``profile`` (the true one unless
    ``tag`` names another; seed 7, the same episodes for every design)."""
    from tumblebot.sim.world.design import Design
    from tumblebot.sim.world.power import energy_per_metre

    csv = folder / f"decision-{tag + '-' if tag else ''}{'-'.join(f'{v:.5f}' for v in design)}.csv"
    if not csv.is_file():
        run = tb("evaluate", "--task", "nav-flat", "--design", ",".join(f"{v:.8g}" for v in design), "--gait", "goto",
                 "--physics", str(profile), "--episodes", str(episodes), "--seed", "7", "--workers", "2",
                 "--csv", str(csv))
        if run.returncode != 0:
            raise SystemExit(f"evaluate failed:\n{run.stderr[-3000:]}")
    R = np.loadtxt(csv, delimiter=",", skiprows=1, usecols=1)
    x, y, z, leg = design
    return np.asarray(R / (energy_per_metre(Design(x, y, z, leg)) + 1.0) ** 3)


def paired(a: np.ndarray, b: np.ndarray) -> float:
    """Paired t-test p of two designs' per-episode objectives (the report's; 1 where they are the same design)."""
    from tumblebot.sim.report import paired_p

    p = paired_p(a, b)
    if p is None:
        raise SystemExit(f"two designs were evaluated on {len(a)} and {len(b)} episodes: not paired")
    return p


def decision(folder: Path, world: Path, fitted_profile: PhysicsProfile, trials: int, seeds: int,
             batch: int = DECISION_BATCH, episodes: int = 480) -> tuple[tuple[int, int, int], list[dict[str, Any]]]:
    """Optimise under the fitted and under the true profile with each optimiser seed; each
    pair of optima on the same episodes under the truth. Returns (seeds where the fitted
    optimum ties or beats the true one, seeds, pairs of true-profile studies of
    neighbouring seeds that tie each other), the last the yardstick, how often the
    optimiser agrees with itself at this budget when it is told the truth; and each seed's
    optima, their objectives under the truth and the paired p. ``fitted_profile`` is the
    profile in ``folder/fitted.json``, already loaded; ``batch`` the studies' full batch."""
    fitted = folder / "fitted.json"
    # the fitted profile's hash names its studies and scores, so that a calibration made
    # again into the same --out (a changed profile) never resumes or reuses the old ones
    tag = f"fitted-{fitted_profile.digest()[:8]}"
    b = "" if batch == DECISION_BATCH else f"-b{batch}"  # a study keeps its batch: another batch, other studies
    fitted_w = [optimum(folder, fitted, f"{tag}{b}-s{s}", trials, s, batch) for s in range(seeds)]
    true_w = [optimum(folder, world, f"true{b}-s{s}", trials, s, batch) for s in range(seeds)]
    f_fit = [objectives(w, world, folder, episodes) for w in fitted_w]
    f_true = [objectives(w, world, folder, episodes) for w in true_w]
    ties = 0
    detail: list[dict[str, Any]] = []
    for s in range(seeds):
        p = paired(f_fit[s], f_true[s])
        detail.append({"seed": s, "fitted_design": fitted_w[s], "fitted_objective": float(f_fit[s].mean()),
                       "true_design": true_w[s], "true_objective": float(f_true[s].mean()), "p": p})
        better = f_fit[s].mean() > f_true[s].mean()
        ties += int(p > 0.05 or bool(better))
        verdict = "tie" if p > 0.05 else ("fitted better" if better else "FITTED WORSE")
        print(f"  decision, seed {s} ({trials} trials each, batch {batch}, {episodes} paired episodes under the true "
              "profile): "
              f"optimum under the fitted profile {tuple(round(v, 3) for v in fitted_w[s])} objective "
              f"{f_fit[s].mean():.5f}; under the true profile {tuple(round(v, 3) for v in true_w[s])} "
              f"{f_true[s].mean():.5f}; paired p = {p:.3g} ({verdict})")
        if verdict == "FITTED WORSE":  # the fit's miss, or the search's? Ask the fitted profile itself
            g_fit, g_true = (objectives(w, fitted, folder, episodes, tag=tag)
                             for w in (fitted_w[s], true_w[s]))
            q = paired(g_fit, g_true)
            order = "tie" if q > 0.05 else ("same" if g_true.mean() > g_fit.mean() else "reversed")
            detail[-1]["under_fitted"] = {"fitted_objective": float(g_fit.mean()),
                                          "true_objective": float(g_true.mean()), "p": q, "order": order}
            print(f"    both scored under the fitted profile: {g_fit.mean():.5f} against {g_true.mean():.5f}, "
                  f"paired p = {q:.3g}: " + {
                      "same": "it ranks them as the truth does, so its study missed a design it rates higher "
                              "(the search's miss)",
                      "tie": "it cannot tell them apart (the fit blurs a difference the truth makes)",
                      "reversed": "it ranks its own optimum higher (the fit's miss)"}[order])
    agree = 0
    for s in range(yardstick_pairs(seeds)):
        t = (s + 1) % seeds
        p = paired(f_true[s], f_true[t])
        agree += int(p > 0.05)
        print(f"  yardstick: the true profile's optima of seeds {s} and {t}: {f_true[s].mean():.5f} against "
              f"{f_true[t].mean():.5f}, paired p = {p:.3g} ({'tie' if p > 0.05 else 'differ'})")
    return (ties, seeds, agree), detail


def yardstick_pairs(seeds: int) -> int:
    """Pairs of neighbouring seeds in a ring of ``seeds`` (one for two seeds, none for one)."""
    return seeds if seeds > 2 else seeds - 1


def _tally(row: dict[str, Any], k: int) -> str:
    """``a/n`` of a decision row's count ``k`` (the fitted ties, or the true-profile yardstick)."""
    if "decision" not in row:
        return f"{'-':16s}"
    ties, seeds, agree = row["decision"]
    n = seeds if k == 0 else yardstick_pairs(seeds)
    return f"{(ties if k == 0 else agree)}/{n}".ljust(16)


def predict(folder: Path, world: Path, fitted: PhysicsProfile, truth: PhysicsProfile, args: argparse.Namespace,
            k: int) -> dict[str, float]:
    """The prediction stage of hidden world ``k``: held-out trials through the twin, closed
    loop (``p_*``) and open loop (``q_*``), against simulation under the fitted profile and
    ``thesis``, and under the true profile, the control (``p_true``, ``q_true``): where the
    truth's own simulation is told apart from the twin's trials, the twin's chain (its
    real-time delays) has moved them, and that run says little about the fit."""
    row: dict[str, float] = {}
    if args.holdout > 0:
        twin(folder / "holdout", world, "nav-flat", args.holdout, seed=100 + k)
        log_med, med_fit, p_fit = prediction(folder / "holdout", fitted)
        _, med_thesis, p_thesis = prediction(folder / "holdout", THESIS)
        _, med_true, p_true = prediction(folder / "holdout", truth)
        print(f"  held-out, closed loop (the policy from the same starts): final distance to the setpoint, logged "
              f"median {log_med:.3f} m; simulated under the fitted profile {med_fit:.3f} m (p = "
              f"{p_fit:.3f}), under thesis {med_thesis:.3f} m (p = {p_thesis:.3f}); control, under the true "
              f"profile {med_true:.3f} m (p = {p_true:.3f})")
        row.update(p_fitted=p_fit, p_thesis=p_thesis, p_true=p_true)
    if args.holdout_open > 0:  # open loop in the twin too, so a replay is the same experiment
        held = folder / f"holdout-{args.holdout_gait}"
        twin(held, world, args.holdout_gait, args.holdout_open, seed=200 + k)
        row["q_fitted"], row["q_thesis"], row["q_true"] = open_loop(held, fitted, truth, args.holdout_gait)
    return row


def calibrated(folder: Path, world: Path, truth: PhysicsProfile, args: argparse.Namespace, k: int
               ) -> tuple[dict[str, Any], PhysicsProfile]:
    """The twin and calibration stages of hidden world ``k`` (recovery, cost, prediction):
    the summary's row so far, and the fitted profile."""
    twin(folder / "excite", world, "excite", args.trials, seed=10 + k)
    result, seconds = calibrate(folder)
    fitted = PhysicsProfile.load(str(folder / "fitted.json"))
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
    row: dict[str, Any] = {"world": truth.name, "recovery": bool(ok and speed_ok), "minutes": seconds / 60,
                           "parameters": result["parameters"]}
    row.update(predict(folder, world, fitted, truth, args, k))
    return row, fitted


def carried_over(earlier: dict[str, Any], truth: PhysicsProfile, folder: Path, source: Path
                 ) -> tuple[dict[str, Any], PhysicsProfile]:
    """The row of ``truth``'s world in an earlier run's summary, and its fitted profile
    (written to ``folder/fitted.json``, where the decision stage reads it)."""
    found = [dict(r) for r in earlier["worlds"] if r["world"] == truth.name]
    if not found:
        raise SystemExit(f"{source} has no world {truth.name!r}")
    fitted = PhysicsProfile.from_json(found[0]["fitted"])
    fitted.write(folder / "fitted.json")
    print(f"\n{truth.describe()}\n  the fitted profile of {source} ({earlier['date']})")
    return found[0], fitted


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trials", type=int, default=15, help="identification trials per hidden world (15)")
    ap.add_argument("--holdout", type=int, default=10, help="held-out policy trials per hidden world (10)")
    ap.add_argument("--holdout-open", type=int, default=15,
                    help="held-out trials of a scripted gait per hidden world, replayed open loop (15)")
    ap.add_argument("--holdout-gait", default="pulse", choices=sorted(GAITS),
                    help="the scripted gait of those trials (pulse: a drive step, then a stopped one)")
    ap.add_argument("--out", type=Path, default=Path("runs/bench-calibrate"), help="where the trial sets go")
    ap.add_argument("--only", type=int, help="run only this hidden world (0, 1, 2)")
    ap.add_argument("--decision-trials", type=int, default=100,
                    help="trials of each optimisation in the decision stage (100; 0 skips it)")
    ap.add_argument("--decision-batch", type=int, default=DECISION_BATCH,
                    help=f"full batch of each optimisation in the decision stage ({DECISION_BATCH}; screening batch 4 "
                         "up to 60, then a fifteenth of it)")
    ap.add_argument("--decision-from", type=Path, metavar="SUMMARY",
                    help="run the decision stage alone on the fitted profiles of an earlier run's summary "
                         "(e.g. benchmarks/results/calibrate.json), its other stages' results carried over; "
                         "no twin, no calibration")
    ap.add_argument("--decision-seeds", type=int, default=3,
                    help="optimiser seeds of the decision stage, each optimising under both profiles (3)")
    ap.add_argument("--json", type=Path, default=Path("benchmarks/results/calibrate.json"),
                    help="where the results go, the fitted profiles included (benchmarks/results/calibrate.json)")
    args = ap.parse_args()
    earlier = json.loads(args.decision_from.read_text()) if args.decision_from is not None else None
    if earlier is not None and args.decision_trials <= 0:
        raise SystemExit("--decision-from runs the decision stage alone: --decision-trials must be above 0")
    args.out.mkdir(parents=True, exist_ok=True)
    print(f"bench_calibrate {time.strftime('%Y-%m-%d')} on {platform.node()} ({os.cpu_count()} cores, "
          f"{platform.processor() or platform.machine()}): " + (
              f"{args.trials} identification trials and {args.holdout} held-out policy trials per hidden world, "
              "through the twin" if earlier is None else
              f"the decision stage alone, on the fitted profiles of {args.decision_from}"))
    load = os.getloadavg()[0]
    if earlier is None and load > 0.5 * (os.cpu_count() or 1):
        print(f"warning: load average {load:.1f} at start; the twin runs in real time, and on a loaded machine "
              "its chain's delays grow and its trials drift from the world it was given (run on an idle machine)")
    rows = []
    for k, hidden in enumerate(HIDDEN):
        if args.only is not None and k != args.only:
            continue
        truth = PhysicsProfile.from_json(hidden)
        folder = args.out / hidden["name"]
        folder.mkdir(exist_ok=True)
        world = folder / "world.json"
        truth.write(world)
        if earlier is None:
            row, fitted = calibrated(folder, world, truth, args, k)
        else:  # the decision alone, on the fitted profile of an earlier run
            row, fitted = carried_over(earlier, truth, folder, args.decision_from)
        if args.decision_trials > 0:
            row["decision"], row["decisions"] = decision(folder, world, fitted, args.decision_trials,
                                                         max(1, args.decision_seeds), args.decision_batch)
            row["decision_budget"] = {"trials": args.decision_trials, "batch": args.decision_batch}
        row.update(truth=truth.to_json(), fitted=fitted.to_json())
        rows.append(row)
    print(f"\n{'':41s}closed loop{'':20s}open loop{'':22s}decision: seeds where")
    print("world                 recovery  minutes  p(fitted) p(thesis) p(true)  p(fitted) p(thesis) p(true)  "
          "fitted ties true   true ties true")
    for r in rows:
        nan = float("nan")
        print(f"{r['world']:21s} {'yes' if r['recovery'] else 'NO':8s} {r['minutes']:7.1f}  "
              f"{r.get('p_fitted', nan):9.3f} {r.get('p_thesis', nan):9.3f} {r.get('p_true', nan):7.3f}  "
              f"{r.get('q_fitted', nan):9.3f} "
              f"{r.get('q_thesis', nan):9.3f} {r.get('q_true', nan):7.3f}  {_tally(r, 0)}  {_tally(r, 2)}")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    summary: dict[str, Any] = {"date": time.strftime("%Y-%m-%d"), "machine": f"{platform.node()} "
                               f"({os.cpu_count()} cores, {platform.processor() or platform.machine()})",
                               "args": {k: str(v) for k, v in vars(args).items()}, "worlds": rows}
    if earlier is not None:  # the twin and calibration stages are the earlier run's
        summary["calibration_stages"] = earlier.get("calibration_stages", {"date": earlier["date"],
                                                                           "machine": earlier["machine"]})
    args.json.write_text(jsonio.dumps(summary) + "\n")
    print(f"wrote {args.json}")
    return 0 if all(r["recovery"] for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
