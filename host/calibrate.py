"""``tumblebot calibrate``: the physics profile of the lab's own robot, from its trial logs.

Reads finished trials of one or more trial sets (ordinary trials and identification runs,
``tumblebot bench excite``, alike), turns each into what the simulator needs to run it
again (:class:`~tumblebot.sim.calibration.Trace`) and what the motion capture saw
(:class:`~tumblebot.sim.calibration.Track`), and fits the profile
(:func:`tumblebot.sim.calibration.calibrate`). Every simulation is appended to a cache
file beside the output as it finishes, so Ctrl-C loses nothing and the same command
resumes; the cache is removed once the profile is written.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from tumblebot.errors import TumblebotError
from tumblebot.host.triallog import read_trial, write_json_atomic
from tumblebot.sim.calibration import Trace, Track, axis_heading

MIN_POSES = 10  #: a finished trial's log with fewer poses than this is not a record of its motion


class CalibrateError(TumblebotError):
    """Trial logs or options a calibration cannot use (one line)."""


@dataclass(frozen=True)
class LoggedTrial:
    trace: Trace
    track: Track


def _plan(folder: Path) -> dict[str, Any]:
    path = folder / "plan.json"
    if not folder.is_dir():
        raise CalibrateError(f"{folder}: no such folder")
    if not path.is_file():
        raise CalibrateError(f"{folder} holds no trial logs (no plan.json: not a trial set)")
    try:
        plan = json.loads(path.read_text())
        design = tuple(float(v) for v in plan["design"])
        period, steps = float(plan["controller"]["period"]), int(plan["controller"]["steps"])
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
        raise CalibrateError(f"{path}: not a readable trial plan ({exc})") from None
    if len(design) != 4 or not all(math.isfinite(v) and v > 0 for v in design) or not (period > 0 and steps > 0):
        raise CalibrateError(f"{path}: its design, period or steps are not valid")
    return {"design": design, "duration": period * steps}


def read_logged_trial(path: Path, design: tuple[float, float, float, float], duration: float) -> LoggedTrial:
    """A finished trial's log as a trace and a track; a corrupt or truncated one is an error."""
    if not path.is_file():
        raise CalibrateError(f"{path}: listed in the set's index.json but missing")
    log = read_trial(path)
    poses = log.topic("/pose")
    decisions = log.topic("/decision")
    if not log.complete or not decisions or len(poses) < MIN_POSES:
        raise CalibrateError(f"{path}: not a complete trial log (corrupt or cut short: {len(poses)} poses, "
                             f"{len(decisions)} decisions)")
    try:
        pt = np.array([float(m.data["t"]) for m in poses])
        xy = np.array([[float(m.data["p"][0]), float(m.data["p"][1])] for m in poses])
        heading = np.array([axis_heading([float(v) for v in m.data["q"]]) for m in poses])
        if all("t" in m.data for m in decisions):
            times = [float(m.data["t"]) for m in decisions]
        else:  # logs from before decisions carried their time: map log time to the pose clock
            offset = float(np.median([m.log_time - float(m.data["t"]) for m in poses]))
            times = [m.log_time - offset for m in decisions]
        commands = [(int(m.data["command"][0]), int(m.data["command"][1])) for m in decisions]
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise CalibrateError(f"{path}: a pose or decision is malformed ({exc})") from None
    if not (np.all(np.isfinite(pt)) and np.all(np.isfinite(xy)) and all(math.isfinite(t) for t in times)):
        raise CalibrateError(f"{path}: non-finite pose or time")
    t0 = times[0]
    before = np.nonzero(pt <= t0)[0]
    i_start = int(before[-1]) if len(before) else 0
    trace = Trace(path.name, design, (float(xy[i_start, 0]), float(xy[i_start, 1]), float(heading[i_start])),
                  tuple((t - t0, r, lft) for t, (r, lft) in zip(times, commands, strict=True)),
                  max(duration, times[-1] - t0 + 1e-3))
    keep = (pt >= pt[i_start]) & (pt <= t0 + trace.duration + 0.05)
    rel = pt[keep] - t0
    rel[0] = min(rel[0], 0.0)
    track = Track(rel, xy[keep, 0], xy[keep, 1], heading[keep])
    return LoggedTrial(trace, track)


def load_trials(folders: list[Path], design: tuple[float, float, float, float] | None = None) -> list[LoggedTrial]:
    """Every finished trial of the sets in ``folders`` (checked all before any work)."""
    from tumblebot.host.trial_sets import TrialError, load_index

    out: list[LoggedTrial] = []
    for folder in folders:
        plan = _plan(folder)
        if design is not None and not np.allclose(plan["design"], design, atol=5e-4):
            raise CalibrateError(f"{folder}: its trials are of design {','.join(f'{v:g}' for v in plan['design'])}, "
                                 f"not --design {','.join(f'{v:g}' for v in design)}")
        try:
            index = load_index(folder)
        except TrialError as exc:
            raise CalibrateError(str(exc)) from None
        trials = index.get("trials") if isinstance(index, dict) else None
        if not trials:
            raise CalibrateError(f"{folder} holds no finished trial logs")
        for entry in trials:
            try:
                name = Path(str(entry["file"])).name
            except (KeyError, TypeError):
                raise CalibrateError(f"{folder}/index.json: a trial without its file") from None
            out.append(read_logged_trial(folder / name, plan["design"], plan["duration"]))
    return out


def cache_path(output: Path) -> Path:
    return output.with_name(f".{output.name}.calibrate-cache.jsonl")


def run_calibration(trials: list[LoggedTrial], folders: list[Path], output: Path, prior: Any, workers: int,
                    settings: Any, plot_path: Path, say: Any, progress: bool = True) -> Any:
    """Fit ``trials`` (read by :func:`load_trials` from ``folders``), write ``output`` (the
    profile) and ``plot_path``; returns the calibration."""
    from tqdm import tqdm

    from tumblebot.sim.calibration import Simulator, calibrate, plot

    say(f"{len(trials)} trials, {sum(len(t.trace.commands) for t in trials)} steps, from "
        f"{', '.join(str(f) for f in folders)}")
    total = settings.simulations()
    bar = tqdm(total=total, unit="set", desc="calibrate", dynamic_ncols=True, mininterval=1.0, disable=not progress)
    sim = Simulator([t.trace for t in trials], workers, cache_path(output), on_done=bar.update)
    if sim.done:
        say(f"resuming: {len(sim.done)} simulated trial sets from {cache_path(output)}")

    def more(n: int) -> None:
        bar.total = (bar.total or 0) + n
        bar.refresh()

    try:
        result = calibrate([t.trace for t in trials], [t.track for t in trials], prior, output.stem, sim, settings,
                           say=lambda line: bar.write(line) if progress else say(line), more=more)
    finally:
        sim.close()
        bar.close()
    write_json_atomic(output, result.profile.to_json())
    plot(result, plot_path)
    cache_path(output).unlink(missing_ok=True)
    return result


def describe(result: Any) -> list[str]:
    """The table ``calibrate`` prints: each parameter, its 90 % interval, and whether the logs pinned it."""
    lines = [f"{'parameter':18s} {'value':>9s}  {'90 % interval':>21s}  identified"]
    for name, p in result.parameters.items():
        if p["identifiable"]:
            lines.append(f"{name:18s} {p['value']:9.4g}  {p['low']:9.4g} .. {p['high']:<9.4g}  yes    {p['unit']}")
        else:
            shown = "(prior kept)" if p["kept_prior"] else "(uncertain)"
            lines.append(f"{name:18s} {p['value']:9.4g}  {shown:>21s}  no     {p['why']}")
    for key, value in result.fit["not_fitted"].items():
        lines.append(f"{key:18s} {value!s:>9s}  {'(prior kept)':>21s}  not fitted")
    lines.append("")
    lines.append(f"{'statistic':24s} {'logged':>8s} {'prior':>8s} {'fitted':>8s} {'noise sd':>9s}")
    for name, s in result.fit["statistics"].items():
        lines.append(f"{name:24s} {s['logged']:8.4f} {s['prior']:8.4f} {s['fitted']:8.4f} {s['noise_sd']:9.4f}")
    lines.append(f"misfit (mean squared, in noise SDs): {result.fit['misfit_prior']:.2f} under the prior, "
                 f"{result.fit['misfit_fitted']:.2f} fitted")
    return lines
