"""``tumblebot demo``: what the simulator can do today, in about a minute.

Until the design optimiser exists this is the project's main job: one scripted episode
of each task, and the power model against thesis Table 3.1.
"""

from __future__ import annotations

from pathlib import Path
from typing import TextIO

from tumblebot.sim.evaluation.episode import run_gait_episode, write_animation
from tumblebot.sim.world.design import THESIS_ROBOTS, Design
from tumblebot.sim.world.power import power_breakdown
from tumblebot.sim.world.tasks import TASKS

#: Thesis Table 3.1 e column (W/m), keyed like THESIS_ROBOTS.
THESIS_E: dict[str, float] = {"0": 6.05, "1": 6.00, "3": 5.20, "inf": 3.76}
DEMO_GAITS: dict[str, str] = {"nav-flat": "alternate", "nav-terrain": "alternate",
                              "distance-flat": "forward", "incline": "forward"}


def _bundled_policies(out: TextIO, robot: Design, seed: int, episodes: int = 12) -> None:
    """The bundled ONNX policies on the same robot, against the same scripted gaits."""
    from tumblebot.sim.control.policy import bundled_policy
    from tumblebot.sim.evaluation.evaluate import Driver, evaluate

    rows = []
    for name in TASKS:
        path = bundled_policy(name)
        if not path.is_file():
            continue
        pol = evaluate(name, robot, Driver("onnx", str(path)), episodes, seed)
        gait = evaluate(name, robot, Driver("gait", DEMO_GAITS[name]), episodes, seed)
        rows.append((name, pol, gait))
    if not rows:
        out.write("No bundled policies yet (policies/TASK.onnx); train one with `tumblebot train`.\n\n")
        return
    out.write(f"Bundled policies, {episodes} randomised episodes each (mean final-state R, 95 % CI)\n")
    for name, pol, gait in rows:
        lo, hi = pol.ci95
        out.write(f"{name:<14} policy {pol.mean_R:+.3f} [{lo:+.3f}, {hi:+.3f}]   "
                  f"gait '{DEMO_GAITS[name]}' {gait.mean_R:+.3f}   median final distance "
                  f"{float(pol.summary()['median_final_distance']):.2f} m\n")
    out.write("\n")


def run_demo(out: TextIO, video_dir: Path | None = None, seed: int = 3) -> None:
    robot = THESIS_ROBOTS["3"]
    out.write(f"tumblebot demo: the thesis's ξ = 3 robot {robot}, scripted gaits, "
              f"domain randomisation on (seed {seed})\n\n")
    out.write(f"{'task':<14} {'gait':<10} {'start → end (x, y) m':<30} {'final R':>8} {'wall s':>7}\n")
    for name in TASKS:
        gait = DEMO_GAITS[name]
        res = run_gait_episode(name, robot, gait, seed, record=video_dir is not None)
        x0, y0, _ = res.steps[0].position
        x1, y1, _ = res.final_position
        path = f"({x0:+.2f}, {y0:+.2f}) → ({x1:+.2f}, {y1:+.2f})"
        out.write(f"{name:<14} {gait:<10} {path:<30} {res.final_R:>8.3f} {res.wall_seconds:>7.2f}\n")
        if video_dir is not None:
            target = video_dir / f"{name}.gif"
            write_animation(res.frames, target)
            out.write(f"{'':<14} wrote {target}\n")
    out.write("\n(Scripted gaits are open-loop baselines: the bar a trained policy has to clear.)\n\n")
    _bundled_policies(out, robot, seed)
    out.write("Power model against thesis Table 3.1 (e in W/m)\n")
    out.write(f"{'ξ':<4} {'x':>6} {'y':>6} {'z':>6} {'l':>6} {'mass kg':>8} {'e ours':>7} {'thesis':>7} {'diff':>7}\n")
    for key, w in THESIS_ROBOTS.items():
        b = power_breakdown(w)
        ref = THESIS_E[key]
        label = "∞" if key == "inf" else key
        out.write(f"{label:<4} {w.x:>6.3f} {w.y:>6.3f} {w.z:>6.3f} {w.l:>6.3f} {b.mass:>8.3f} "
                  f"{b.e:>7.3f} {ref:>7.2f} {100 * (b.e / ref - 1):>+6.2f}%\n")
    out.flush()
