"""Trial sets for calibration tests, faster than the twin: each trial is the identification
run replayed in a simulator under a hidden profile, written as the host writes trial logs
(``plan.json``, ``index.json``, one MCAP per trial with ``/pose`` at 60 Hz and ``/decision``
with the time each command left). The twin's own trial sets test the deployed stack
(``hil_tests/test_calibrate_twin.py``); these test the fit, where the world is known."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from tumblebot.host.trial_runner import ControllerConfig
from tumblebot.host.trial_sets import make_plan, open_trial_set
from tumblebot.host.triallog import TrialLogWriter, write_json_atomic
from tumblebot.sim.calibration import Trace, replay
from tumblebot.sim.control.gaits import EXCITATION
from tumblebot.sim.world.design import THESIS_ROBOTS, Design
from tumblebot.sim.world.frames import yaw_quaternion
from tumblebot.sim.world.physics import PhysicsProfile

XI3 = THESIS_ROBOTS["3"]


def write_set(folder: Path, hidden: PhysicsProfile, trials: int, seed: int = 0, design: Design = XI3) -> Path:
    """A finished identification trial set of ``trials`` trials on 5 start points."""
    plan = make_plan((0.0, 0.0), 0.0, 1.0, 5, max(1, trials // 5), "nav-flat", "excite", design, seed,
                     ControllerConfig())
    plan = open_trial_set(folder, plan)
    env = hidden.make_env("nav-flat")
    rng = np.random.default_rng(seed)
    index: dict[str, list[dict[str, object]]] = {"trials": [], "aborted": []}
    try:
        for trial in range(trials):
            point = plan.start_point(plan.point_of(trial))
            jitter = rng.uniform(0.0, 0.004, 20)  # the host's decisions are a few ms late
            commands = tuple((k + (jitter[k] if k else 0.0), a - 1, b - 1) for k, (a, b) in enumerate(EXCITATION))
            trace = Trace(f"trial-{trial}", design.as_tuple(), (point[0], point[1], plan.start_yaw(trial)), commands,
                          20.0)
            track = replay(env, trace, 1000 + trial + 7919 * seed)
            clock = 5000.0 + 100.0 * trial  # host monotonic time of the first command
            name = f"trial-{trial:04d}.mcap"
            with TrialLogWriter(folder / name, {"trial": str(trial)}) as log:
                for t, x, y, heading in zip(track.t, track.x, track.y, track.heading, strict=True):
                    log.write("/pose", {"t": clock + float(t), "p": [float(x), float(y), 0.06],
                                        "q": [float(v) for v in yaw_quaternion(float(heading))]}, t=clock + float(t))
                    for k, (tc, r, lft) in enumerate(commands):
                        if t <= tc < t + 1.0 / 60:
                            log.write("/decision", {"step": k, "t": clock + tc, "command": [r, lft]}, t=clock + tc)
            index["trials"].append({"trial": trial, "point": plan.point_of(trial), "start": list(point), "file": name,
                                    "final_position": [float(track.x[-1]), float(track.y[-1]), 0.06],
                                    "final_error": math.hypot(float(track.x[-1]), float(track.y[-1]))})
    finally:
        env.close()
    write_json_atomic(folder / "index.json", index)
    return folder
