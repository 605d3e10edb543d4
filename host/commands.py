"""``tumblebot trial …`` and ``tumblebot twin …``: the host's commands."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

from tumblebot.defaults import XI3_ROBOT_TEXT
from tumblebot.errors import TumblebotError
from tumblebot.paths import check_writable_folder
from tumblebot.pi_agent.protocol import NEUTRAL_SPREAD_US, NEUTRAL_US


def _xy(text: str) -> tuple[float, float]:
    parts = text.split(",")
    try:
        x, y = (float(p) for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} must be two numbers X,Y (metres)") from None
    if not (math.isfinite(x) and math.isfinite(y)):
        raise argparse.ArgumentTypeError(f"{text!r} must be finite")
    return x, y


def _neutral_pair(text: str) -> tuple[float, float]:
    right, left = _xy(text)
    if not (1300 <= right <= 1700 and 1300 <= left <= 1700):
        raise argparse.ArgumentTypeError(f"{text!r}: neutral pulses are 1300–1700 µs")
    return right, left


def say(message: str) -> None:
    """One line to stdout in one write (the log thread may print ``@written`` lines too)."""
    sys.stdout.write(message + "\n")
    sys.stdout.flush()


def say_status(message: str) -> None:
    """A live status line: rewritten in place; an empty message ends it."""
    sys.stdout.write(f"\r{message}" if message else "\n")
    sys.stdout.flush()


def _policy_path(name: str) -> Path:
    from tumblebot.sim.control.policy import PolicyError, bundled_policy

    path = bundled_policy(name) if not name.endswith(".onnx") else Path(name)
    if not path.is_file():
        raise PolicyError(f"policy {name!r}: {path} does not exist (give a task with a bundled policy, "
                          "or a .onnx file)")
    return path


def _trial_policy(args: argparse.Namespace, design: Any, task: str) -> tuple[Any, Path | str]:
    """The controller ``trial run`` drives with (the bundled policy, an ONNX file, goto or
    plan) and what the plan records."""
    if args.gait is not None:
        if args.policy is not None:
            raise TumblebotError("give --policy or --gait, not both")
        from tumblebot.sim.control.goto import NAVIGATORS, GotoPolicy

        if args.gait not in NAVIGATORS:
            from tumblebot.sim.control.gaits import GaitPolicy

            return GaitPolicy(args.gait, args.seed), args.gait  # an unknown gait is one error line
        return GotoPolicy(args.steps, args.gait), args.gait
    from tumblebot.sim.control.policy import OnnxPolicy

    policy_path = _policy_path(args.policy or "nav-flat")
    policy = OnnxPolicy(policy_path, task=task)
    policy.bind_design(design.as_tuple())  # a design-conditioned policy is told the body it drives
    return policy, policy_path


def _trial_run(args: argparse.Namespace) -> int:
    from tumblebot.host.link import AgentClient, load_host_key, parse_address
    from tumblebot.host.live import LiveView, parse_listen
    from tumblebot.host.mocap import open_source
    from tumblebot.host.trial_runner import ControllerConfig, TrialRunner
    from tumblebot.host.trial_sets import OperatorPlacer, TwinPlacer, make_plan, open_trial_set, run_trial_set
    from tumblebot.sim.world.design import Design

    design = Design.parse(args.design)
    task = "nav-flat"
    policy, policy_path = _trial_policy(args, design, task)
    config = ControllerConfig(period=args.period, steps=args.steps, lost_after=args.lost_after,
                              agent_timeout=args.agent_timeout, max_speed=args.max_speed)
    plan = make_plan(args.setpoint, args.heading, args.radius, args.points, args.per_point, task, policy_path,
                     design, args.seed, config)
    key = load_host_key(args.key)  # everything is checked before the trial set is created or touched
    check_writable_folder(args.out, "--out")
    address = parse_address(args.agent)
    twin = parse_address(args.twin) if args.twin else None
    listen = parse_listen(args.foxglove) if args.foxglove is not None else None
    source = open_source(args.mocap)
    live = None
    try:
        if listen is not None:
            live = LiveView(*listen)
            say(f"live view: open {live.url} in Foxglove (layout: docs/foxglove-layout.json)")
        plan = open_trial_set(args.out, plan)
    except BaseException:
        source.close()
        if live is not None:
            live.close()
        raise
    agent = AgentClient(address, key)
    if args.take_over and not agent.claim_control():
        source.close()
        agent.close()
        raise TumblebotError(f"--take-over: the agent at {args.agent} did not hand control to this host")
    placer = TwinPlacer(twin) if twin else OperatorPlacer(source, out=say, status=say_status)
    controller = TrialRunner(source, agent, policy, plan.setpoint, plan.heading, config)

    def on_logged(seq: int) -> None:
        if args.print_writes:
            sys.stdout.write(f"@written {seq}\n")
            sys.stdout.flush()

    try:
        index = run_trial_set(args.out, plan, controller, placer, out=say, agent_wait=args.agent_wait,
                              on_logged=on_logged, mirror=live.publish if live is not None else None)
    except KeyboardInterrupt:
        print(f"\nstopped; the robot was told to stop. Finished trials are in {args.out}/index.json; "
              "run the same command to resume.", file=sys.stderr)
        return 130
    finally:
        source.close()
        agent.close()
        if live is not None:
            live.close()
    print(f"trial set complete: {len(index['trials'])} trials in {args.out}")
    return 0


def _trial_analyze(args: argparse.Namespace) -> int:
    from tumblebot.host.trial_sets import analyze

    stats = None
    given = [args.baseline_mean, args.baseline_sd, args.baseline_n]
    if any(v is not None for v in given):
        if any(v is None for v in given):
            raise TumblebotError("give all of --baseline-mean, --baseline-sd and --baseline-n")
        stats = (float(args.baseline_mean), float(args.baseline_sd), int(args.baseline_n))
    plot = args.plot or args.dir / "analysis.png"
    result = analyze(args.dir, args.baseline, stats, plot)
    if args.json:
        print(json.dumps(result))
        return 0
    spread = (f"95 % CI {_interval(result['ci95'])}, sd {result['sd_error']:.3f}" if result["ci95"] is not None
              else "no CI from one trial")
    print(f"{args.dir}: {result['n']} trials, mean setpoint error {result['mean_error']:.3f} m ({spread})")
    for pp in result["per_point"]:
        interval = _interval(pp["ci95"]) if pp["ci95"] is not None else "no CI from one trial"
        print(f"  start point {pp['point'] + 1} ({pp['start'][0]:+.2f}, {pp['start'][1]:+.2f}): n={pp['n']}, "
              f"mean {pp['mean_error']:.3f} m ({interval})")
    e = result["e"]
    print("  robot ({:.3f}, {:.3f}, {:.3f}, {:.3f}): e(w) = ".format(*result["design"])
          + (f"{e:.2f} W/m" if e is not None else "inf (cannot tumble)"))
    if "baseline" in result:
        b = result["baseline"]
        test = f"Welch t-test p = {b['p']:.3g}" if b["p"] is not None else \
            "no t-test (each side needs two trials or more)"
        line = f"baseline: n={b['n']}, mean {b['mean_error']:.3f} m (sd {b['sd_error']:.3f}); {test}"
        if b.get("e") is not None:
            line += f"; baseline e(w) = {b['e']:.2f} W/m"
        print(line)
    print(f"trajectories: {result['plot']}")
    return 0


def _interval(ci: list[float] | tuple[float, float]) -> str:
    return f"{ci[0]:.3f} … {ci[1]:.3f}"


def _twin_world(args: argparse.Namespace) -> int:
    from tumblebot.host.link import load_host_key, parse_address
    from tumblebot.host.twin import MOUNTING, ServoHardware, run_world
    from tumblebot.sim.world.design import Design
    from tumblebot.sim.world.physics import PhysicsProfile

    right, left = (-MOUNTING[s] if s in args.reverse_servo else MOUNTING[s] for s in ("right", "left"))
    hardware = ServoHardware(neutral=args.servo_neutral, mounting=(right, left))
    physics = PhysicsProfile.load(args.world_physics) if args.world_physics is not None else None
    pose_key = load_host_key(args.pose_key) if args.pose_key is not None else None
    return run_world(parse_address(args.pose_to), parse_address(args.control), args.serial_link,
                     Design.parse(args.design), args.seed, servo=_servo_of(args), hardware=hardware, physics=physics,
                     pose_key=pose_key)


def _twin_run(args: argparse.Namespace) -> int:
    from tumblebot.host.twin import consistency, run_twin
    from tumblebot.sim.world.design import Design

    servo = _servo_of(args)
    from tumblebot.sim.control.drivers import Driver
    from tumblebot.sim.control.gaits import GAITS

    if args.policy not in GAITS:
        Driver("onnx", str(_policy_path(args.policy)), args.allow_servo_mismatch).check("nav-flat", servo)
    elif args.check:
        raise TumblebotError(f"--check compares a policy's trials with simulation; a scripted gait (--policy "
                             f"{args.policy}) runs open loop: give its trials to tumblebot calibrate")
    if args.foxglove is not None:
        from tumblebot.host.live import parse_listen

        parse_listen(args.foxglove)  # a bad address is refused before the twin starts
    if args.world_physics is not None:
        from tumblebot.sim.world.physics import PhysicsProfile

        PhysicsProfile.load(str(args.world_physics))  # a bad profile is refused before the twin starts
    code = run_twin(args.out, args.points, args.per_point, args.radius, args.setpoint, args.heading,
                    Design.parse(args.design), args.seed, args.policy, servo=servo, world_physics=args.world_physics,
                    extra=["--foxglove", args.foxglove] if args.foxglove is not None else None)
    if code != 0:
        return code
    if args.check:
        result = consistency(args.out, args.sim_episodes)
        _print_consistency(result)
        (args.out / "consistency.json").write_text(json.dumps(result, indent=2) + "\n")
        return 0 if result["consistent"] else 1
    return 0


def _twin_check(args: argparse.Namespace) -> int:
    from tumblebot.host.twin import consistency

    result = consistency(args.dir, args.sim_episodes)
    _print_consistency(result)
    return 0 if result["consistent"] else 1


def _servo_of(args: argparse.Namespace) -> Any:
    from tumblebot.sim.world.physics import PhysicsProfile

    return PhysicsProfile.from_arguments(args.physics, args.motor_model, args.stall_torque)


def _add_servo(p: argparse.ArgumentParser) -> None:
    p.add_argument("--physics", default=None, metavar="NAME|FILE",
                   help="the simulated world's physics profile, which the host's policy is checked against: the "
                        "built-in thesis (default) or a JSON file")
    p.add_argument("--motor-model", choices=("dc", "velocity"), default=None,
                   help="the simulated world's servo model (default the profile's, dc)")
    p.add_argument("--stall-torque", type=float, default=None, metavar="N·m",
                   help="the simulated servo's stall torque (default 0.582, the thesis's constants)")


def _print_consistency(r: dict[str, Any]) -> None:
    verdict = "CONSISTENT" if r["consistent"] else "NOT CONSISTENT"
    print(f"twin: median error {r['twin_median_error']:.3f} m over {r['twin_n']} trials; pure simulation from the "
          f"same starts: median {r['sim_median_error']:.3f} m over {r['sim_n']} episodes; twin errors too large "
          f"for their starts? p = {r['p']:.3g} (per-start ranks, alpha {r['alpha']}): {verdict}")


def _bench(args: argparse.Namespace, with_mocap: bool, expected_neutral: tuple[int, int] | None = None) -> Any:
    """The agent (and the pose source) a bench command talks to; everything checked first."""
    from tumblebot.host.bench import Bench, operator_if_terminal
    from tumblebot.host.link import AgentClient, load_host_key, parse_address
    from tumblebot.host.mocap import open_source

    key = load_host_key(args.key)
    address = parse_address(args.agent)
    source = open_source(args.mocap) if with_mocap and args.mocap else None
    agent = AgentClient(address, key)
    if args.take_over and not agent.claim_control():
        agent.close()
        if source is not None:
            source.close()
        raise TumblebotError(f"--take-over: the agent at {args.agent} did not hand control to this host")
    return Bench(agent, source, ask=operator_if_terminal(), say=say, expected_neutral=expected_neutral)


def _close(bench: Any) -> None:
    bench.agent.close()
    if bench.source is not None:
        bench.source.close()


def _trim(args: argparse.Namespace) -> int:
    from tumblebot.host.bench import format_trims, read_trims, set_trim

    changes = [args.neutral, args.nudge, args.direction]
    if args.servo is None and any(v is not None for v in changes):
        raise TumblebotError("--neutral, --nudge and --direction need --servo right|left")
    if args.neutral is not None and args.nudge is not None:
        raise TumblebotError("give --neutral or --nudge, not both")
    if args.servo is not None and all(v is None for v in changes):
        raise TumblebotError(f"--servo {args.servo}: say what to change (--neutral US, --nudge US or --direction ±1)")
    bench = _bench(args, with_mocap=False)
    try:
        if args.servo is None:
            trims = read_trims(bench)
            print(json.dumps(trims) if args.json else f"trims: {format_trims(trims)}")
            return 0
        before, after = set_trim(bench, args.servo, args.neutral, args.nudge, args.direction)
    finally:
        _close(bench)
    if args.json:
        print(json.dumps({"servo": args.servo, "before": before, "after": after}))
    else:
        print(f"{args.servo} servo: neutral {before['neutral_us']} → {after['neutral_us']} µs, direction "
              f"{before['direction']:+d} → {after['direction']:+d} (stored in the Arduino's EEPROM)")
    return 0


def _bench_check(args: argparse.Namespace) -> int:
    from tumblebot.host.bench import check

    bench = _bench(args, with_mocap=True, expected_neutral=args.neutral_us)
    if not args.json:
        say(f"bench check of the agent at {args.agent}" + (f" with poses from {args.mocap}" if args.mocap else "")
            + ": the robot will move (leave it 0.5 m of clear floor)")
    try:
        checks = check(bench)
    finally:
        _close(bench)
    passed = all(c.ok for c in checks)
    if args.json:
        print(json.dumps({"passed": passed, "checks": [c.to_json() for c in checks]}))
    else:
        for c in checks:
            say(c.line())
        say("all checks passed" if passed else "NOT READY: fix what failed and run bench check again")
    return 0 if passed else 1


def _bench_excite(args: argparse.Namespace) -> int:
    """The identification run: ``trial run --gait excite`` with the trial protocol's defaults."""
    if args.points < 1 or args.per_point < 1:
        raise TumblebotError("--points and --per-point must be at least 1")
    run = argparse.Namespace(**vars(args), gait="excite", policy=None, heading=0.0, steps=20, period=1.0,
                             lost_after=0.5, agent_timeout=1.5, agent_wait=300.0, max_speed=3.0, foxglove=None,
                             print_writes=False)
    return _trial_run(run)


def _add_link_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--agent", required=True, help="the Pi agent's HOST:PORT (UDP, default port 47800)")
    p.add_argument("--key", type=Path, required=True, help="the shared 32-byte key file (mode 600)")
    p.add_argument("--json", action="store_true", help="print the result as one JSON object")
    p.add_argument("--take-over", action="store_true",
                   help="take control of the robot from another host on the same key (it is told, and stops)")


def _microseconds(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number of microseconds") from None


def _neutral(text: str) -> int:
    value = _microseconds(text)
    if not 1300 <= value <= 1700:
        raise argparse.ArgumentTypeError(f"{value} µs is outside 1300–1700 µs")
    return value


def _nudge(text: str) -> int:
    value = _microseconds(text)
    if not -400 <= value <= 400:
        raise argparse.ArgumentTypeError(f"{value} µs: a nudge is at most ±400 µs")
    return value


def _direction(text: str) -> int:
    if text not in ("+1", "1", "-1"):
        raise argparse.ArgumentTypeError(f"{text!r} must be +1 or -1")
    return int(text)


def _neutral_int_pair(text: str) -> tuple[int, int]:
    parts = text.split(",")
    if len(parts) != 2:
        raise argparse.ArgumentTypeError(f"{text!r} must be two neutral pulses RIGHT,LEFT (µs)")
    right, left = (_neutral(p) for p in parts)
    return right, left


def _add_bench_commands(sub: Any) -> None:
    t = sub.add_parser("trim", help="show or set the servos' neutral pulse and direction (stored on the Arduino)",
                       description="Show the trims the Arduino holds, or set one servo's: its neutral pulse (the "
                                   "width at which it stands still) and its direction (+1, or -1 for a servo "
                                   "mounted mirrored). The agent forwards a trim only while the robot is stopped; "
                                   "the firmware keeps it in EEPROM.")
    _add_link_args(t)
    t.add_argument("--servo", choices=("right", "left"), help="the servo to set (right: D9, left: D10)")
    t.add_argument("--neutral", type=_neutral, metavar="US", help="its neutral pulse, µs (1300–1700)")
    t.add_argument("--nudge", type=_nudge, metavar="US", help="move its neutral by this many µs (e.g. -5)")
    t.add_argument("--direction", type=_direction, metavar="±1", help="+1 or -1: which way is forward")
    t.set_defaults(func=_trim)
    b = sub.add_parser("bench", help="bring-up checks before a trial set",
                       description="Bring-up checks of the robot through its agent.")
    bsub = b.add_subparsers(dest="bench_command", required=True, metavar="{check,excite}")
    c = bsub.add_parser("check", help="is the robot ready for a trial set? one line per check",
                        description="Check, one line each: the agent answers; the Arduino is connected (epoch, "
                                    "firmware version); its trims; the motion capture sees the robot with z up; the "
                                    "robot keeps still when stopped; each servo turns both ways when told; the legs "
                                    "stop when the host falls silent. With --mocap the motion is measured from the "
                                    "poses, without it an operator at the terminal confirms. Exit 0 only when every "
                                    "check holds. The robot moves: leave it 0.5 m of clear floor.")
    _add_link_args(c)
    c.add_argument("--mocap", help="pose source, as for trial run (udp://HOST:PORT?body=B, motioncapture://…)")
    c.add_argument("--neutral-us", type=_neutral_int_pair, metavar="RIGHT,LEFT",
                   help="the servos' neutral pulses the trim procedure found, µs: the trims must be these "
                        f"(default: each within {NEUTRAL_SPREAD_US} µs of {NEUTRAL_US})")
    c.set_defaults(func=_bench_check)
    e = bsub.add_parser("excite", help="the identification run: scripted drives, spins and stops, logged for calibrate",
                        description="A trial set of scripted commands instead of a policy: drives both ways, spins "
                                    "both ways, one leg at a time and stops after motion (20 steps a trial), from "
                                    "the trial protocol's start points, logged like any trial (resume it with the "
                                    "same command). tumblebot calibrate takes it and ordinary trials alike. The "
                                    "robot moves about a metre from each start point: give it room.")
    e.add_argument("--agent", required=True, help="the Pi agent's HOST:PORT (UDP, default port 47800)")
    e.add_argument("--key", type=Path, required=True, help="the shared 32-byte key file (mode 600)")
    e.add_argument("--take-over", action="store_true",
                   help="take control of the robot from another host on the same key (it is told, and stops)")
    e.add_argument("--mocap", required=True, help="pose source, as for trial run (udp://HOST:PORT?body=B, …)")
    e.add_argument("--out", type=Path, required=True, help="trial-set folder (created; an existing one is resumed)")
    e.add_argument("--design", required=True, help="the robot's design x,y,z,l (m)")
    e.add_argument("--setpoint", type=_xy, default=(0.0, 0.0), help="centre of the start circle X,Y (default 0,0)")
    e.add_argument("--radius", type=float, default=1.0, help="start circle radius, m (default 1)")
    e.add_argument("--points", type=int, default=5, help="start points (default 5)")
    e.add_argument("--per-point", type=int, default=3, help="runs per start point (default 3)")
    e.add_argument("--seed", type=int, default=0, help="seed of the placement headings (default 0)")
    e.add_argument("--twin", help="HOST:PORT of a digital twin's world, which then places the robot itself")
    e.set_defaults(func=_bench_excite)


def add_commands(sub: Any, positive_int: Any, check_writable: Any) -> None:
    """Add ``trial``, ``twin``, ``trim``, ``bench`` and ``calibrate`` to the ``tumblebot``
    parser's subcommands."""
    _add_trial_commands(sub, positive_int)
    _add_twin_commands(sub, positive_int)
    _add_bench_commands(sub)
    _add_calibrate_command(sub, positive_int, check_writable)


def _calibrate(args: argparse.Namespace) -> int:
    from tumblebot.host.calibrate import describe, run_calibration
    from tumblebot.sim.calibration import Settings
    from tumblebot.sim.world.design import Design
    from tumblebot.sim.world.physics import PhysicsProfile

    if args.output.suffix != ".json":
        raise TumblebotError(f"-o {args.output}: a physics profile is a .json file")
    plot = args.plot if args.plot is not None else args.output.with_name("calibration.png")
    if plot.suffix != ".png":
        raise TumblebotError(f"--plot {plot}: the picture is a .png file")
    args.check_writable(args.output, "-o")
    args.check_writable(plot, "--plot")
    prior = PhysicsProfile.load(args.prior)
    design = Design.parse(args.design).as_tuple() if args.design is not None else None
    settings = Settings(design_points=args.budget, seed=args.seed)
    from tumblebot.host.calibrate import load_trials

    trials = load_trials(args.trialdir, design)  # every log is checked before any work or write
    quiet = args.json

    def note(line: str) -> None:
        if not quiet:
            say(line)

    try:
        result = run_calibration(trials, args.trialdir, args.output, prior, args.workers, settings, plot, note,
                                 progress=not quiet and sys.stderr.isatty())
    except KeyboardInterrupt:
        from tumblebot.host.calibrate import cache_path

        print(f"\nstopped; nothing was written but the simulations so far ({cache_path(args.output)}): run the "
              "same command to resume", file=sys.stderr)
        return 130
    if args.json:
        print(json.dumps({"parameters": {k: {f: v[f] for f in ("value", "low", "high", "identifiable", "unit",
                                                                 "kept_prior", "effect", "why")}
                                         for k, v in result.parameters.items()},
                          "fit": result.fit, "profile": result.profile.record(), "plot": str(plot)}))
        return 0
    for line in describe(result):
        say(line)
    say(f"wrote {args.output} and {plot}; next: tumblebot optimize --physics {args.output}, "
        f"tumblebot report --physics {args.output}")
    return 0


def _add_calibrate_command(sub: Any, positive_int: Any, check_writable: Any) -> None:
    c = sub.add_parser(
        "calibrate", help="fit a physics profile to trial logs: the simulator of the robot the lab built",
        description="Re-simulate each logged trial from its start pose and leg commands under candidate physics "
                    "profiles and fit the profile under which the simulated motion matches what the motion capture "
                    "saw (per-step distance and turn, how soon steps get under way). Prints each parameter with a "
                    "90 % interval, or says that the logs cannot pin it down (it then keeps the prior's value); "
                    "writes the profile and calibration.png. Ctrl-C is safe and the same command resumes.")
    c.add_argument("trialdir", type=Path, nargs="+", metavar="TRIALDIR",
                   help="trial-set folders (tumblebot trial run, bench excite or twin run)")
    c.add_argument("-o", "--output", type=Path, required=True, metavar="PROFILE", help="the fitted profile (.json)")
    c.add_argument("--prior", default="thesis", metavar="NAME|FILE",
                   help="the profile to start from; kept for what the logs cannot identify (default thesis)")
    c.add_argument("--design", help="refuse logs of any other design x,y,z,l (m)")
    c.add_argument("--plot", type=Path, help="the fit's picture (default calibration.png beside PROFILE)")
    c.add_argument("--budget", type=positive_int, default=128,
                   help="simulated trial sets in the first round (default 128, at least 64; the second has half, "
                        "at least 64)")
    c.add_argument("--workers", type=positive_int, default=2, help="worker processes (default 2)")
    c.add_argument("--seed", type=int, default=0, help="seed of the fit's designs and simulations (default 0)")
    c.add_argument("--json", action="store_true",
                   help='print {"parameters": {NAME: {"value", "low", "high", "identifiable", ...}}, "fit": {...}}')
    c.set_defaults(func=_calibrate, check_writable=check_writable)


def _add_trial_commands(sub: Any, positive_int: Any) -> None:
    p = sub.add_parser("trial", help="field trials: run a trial set with the robot, analyse it",
                       description="Field trials (thesis §3.3): start points on a circle around a setpoint, several "
                                   "trials each, the policy driving the robot from mocap poses.")
    tsub = p.add_subparsers(dest="trial_command", required=True, metavar="{run,analyze}")
    r = tsub.add_parser("run", help="run (or resume) a trial set",
                        description="Guide the operator through a trial set: where to place the robot, its live "
                                    "distance, then the trial. Each trial is logged to its own crash-safe MCAP file; "
                                    "finished trials survive any interruption and the same command resumes the set.")
    r.add_argument("--out", type=Path, required=True, help="trial-set folder (created; an existing one is resumed)")
    r.add_argument("--mocap", required=True, help="pose source: udp://HOST:PORT?body=B, "
                                                  "motioncapture://vicon@HOST?body=B, replay:///FILE.mcap, mock://")
    r.add_argument("--agent", required=True, help="the Pi agent's HOST:PORT (UDP, default port 47800)")
    r.add_argument("--key", type=Path, required=True, help="the shared 32-byte key file (mode 600)")
    r.add_argument("--design", required=True, help="the robot's design x,y,z,l (m), for its e(w) and the records")
    r.add_argument("--policy", default=None, help="nav-flat (the bundled policy, the default) or an ONNX file")
    r.add_argument("--gait", default=None, metavar="goto|plan|plan-short|GAIT",
                   help="drive the trials with goto, plan or plan-short, the hand-written closed-loop controllers, "
                        "or with a scripted gait (excite: the identification run of tumblebot calibrate), instead of a "
                        "policy")
    r.add_argument("--setpoint", type=_xy, default=(0.0, 0.0), help="lab-frame goal X,Y (default 0,0)")
    r.add_argument("--heading", type=float, default=0.0, help="lab-frame heading (rad) of the task frame's +x")
    r.add_argument("--radius", type=float, default=1.5, help="start circle radius, m (default 1.5)")
    r.add_argument("--points", type=positive_int, default=5, help="start points (default 5)")
    r.add_argument("--per-point", type=positive_int, default=10, help="trials per start point (default 10)")
    r.add_argument("--steps", type=positive_int, default=20, help="decisions per trial (default 20)")
    r.add_argument("--period", type=float, default=1.0, help="seconds between decisions (default 1)")
    r.add_argument("--lost-after", type=float, default=0.5, help="seconds without a pose = tracking lost (0.5)")
    r.add_argument("--agent-timeout", type=float, default=1.5, help="seconds without telemetry = agent lost (1.5)")
    r.add_argument("--agent-wait", type=float, default=300.0, help="seconds to wait for a lost agent (300)")
    r.add_argument("--max-speed", type=float, default=3.0, help="m/s; faster pose jumps are outliers (3)")
    r.add_argument("--seed", type=int, default=0, help="seed of the placement headings and the twin's episodes")
    r.add_argument("--twin", help="HOST:PORT of a digital twin's world, which then places the robot itself")
    r.add_argument("--take-over", action="store_true",
                   help="take control of the robot from another host on the same key (it is told, and stops)")
    r.add_argument("--foxglove", metavar="[HOST:]PORT",
                   help="also stream the trials live to Foxglove: a WebSocket server on PORT (loopback unless HOST "
                        "is given; 0 picks a free port), carrying what the trial logs carry")
    r.add_argument("--print-writes", action="store_true",
                   help="print '@written N' after each log message is on disk (for crash-safety tests)")
    r.set_defaults(func=_trial_run)

    a = tsub.add_parser("analyze", help="setpoint errors, CIs, a t-test against a baseline, trajectories",
                        description="Report the final setpoint error per start point and overall with 95 % CIs, a "
                                    "Welch t-test against a baseline trial set or published numbers (the thesis: "
                                    "0.433 m over 100 trials), e(w) of each robot, and a PNG of the trajectories.")
    a.add_argument("dir", type=Path, help="trial-set folder")
    a.add_argument("--baseline", type=Path, help="another trial-set folder to compare against")
    a.add_argument("--baseline-mean", type=float, help="baseline mean error, m (e.g. 0.433)")
    a.add_argument("--baseline-sd", type=float, help="baseline standard deviation, m")
    a.add_argument("--baseline-n", type=int, help="baseline number of trials (e.g. 100)")
    a.add_argument("--plot", type=Path, help="PNG of the trajectories (default DIR/analysis.png)")
    a.add_argument("--json", action="store_true", help="print the result as one JSON object")
    a.set_defaults(func=_trial_analyze)


def _add_twin_commands(sub: Any, positive_int: Any) -> None:
    p = sub.add_parser("twin", help="the digital twin: the deployed stack against the simulator and the firmware",
                       description="Simulator as world and robot, the real firmware in simavr, the real Pi agent "
                                   "and the real host controller, each its own process over the lab's links.")
    wsub = p.add_subparsers(dest="twin_command", required=True, metavar="{run,check,world}")
    t = wsub.add_parser("run", help="run a trial set through the twin (and check it against pure simulation)",
                        description="Run a field-trial set through the digital twin: the simulator as world and "
                                    "robot, the real firmware in simavr, the real Pi agent and the real host "
                                    "controller, each its own process; then (--check) compare the final errors "
                                    "with pure simulation from the same starts. Needs the agent extra (pyserial) "
                                    "and Debian's avr-gcc and simavr (./dev.sh test installs them).")
    t.add_argument("--out", type=Path, required=True, help="trial-set folder")
    t.add_argument("--design", default=XI3_ROBOT_TEXT, help="robot design (default: the ξ = 3 robot)")
    t.add_argument("--policy", default="nav-flat",
                   help="nav-flat, an ONNX file, or a scripted gait run open loop (excite: the identification run "
                        "of tumblebot bench excite; forward, pulse, …: held-out trials for a calibration)")
    t.add_argument("--setpoint", type=_xy, default=(0.4, -0.3), help="lab-frame goal X,Y (default 0.4,-0.3)")
    t.add_argument("--heading", type=float, default=0.5, help="task-frame heading, rad (default 0.5)")
    t.add_argument("--radius", type=float, default=1.5, help="start circle radius, m (default 1.5)")
    t.add_argument("--points", type=positive_int, default=3, help="start points (default 3)")
    t.add_argument("--per-point", type=positive_int, default=1, help="trials per start point (default 1)")
    t.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    t.add_argument("--check", action="store_true", help="then test consistency with pure simulation")
    t.add_argument("--sim-episodes", type=positive_int, default=16, help="simulated episodes per twin trial (16)")
    t.add_argument("--foxglove", metavar="[HOST:]PORT",
                   help="stream the twin's trials live to Foxglove (as trial run --foxglove)")
    _add_servo(t)
    t.add_argument("--world-physics", type=Path, metavar="PROFILE",
                   help="run the twin's world under this physics profile (JSON file), which the host, the policy "
                        "and a calibration are not told: the twin as a lab whose robot differs from the simulator")
    t.add_argument("--allow-servo-mismatch", action="store_true",
                   help="run a policy under a servo other than the one it was trained under")
    t.set_defaults(func=_twin_run)
    c = wsub.add_parser("check", help="test a twin trial set for consistency with pure simulation",
                        description="Compare each twin trial's final setpoint error with simulated episodes from "
                                    "the same start and heading (rank p-values, combined with Fisher's method): "
                                    "NOT CONSISTENT when the twin's errors are too large at alpha = 0.01.")
    c.add_argument("dir", type=Path, help="the trial-set folder a twin run wrote (twin run --out)")
    c.add_argument("--sim-episodes", type=positive_int, default=16, help="simulated episodes per twin trial (16)")
    c.set_defaults(func=_twin_check)
    w = wsub.add_parser("world", help="the world process alone (started by twin run)")
    w.add_argument("--pose-to", required=True, help="HOST:PORT to send the pose stream to")
    w.add_argument("--control", required=True, help="HOST:PORT to listen on for placement requests")
    w.add_argument("--serial-link", type=Path, required=True, help="path for a symlink to the firmware's pty")
    w.add_argument("--design", required=True)
    w.add_argument("--seed", type=int, default=0)
    w.add_argument("--servo-neutral", type=_neutral_pair, default=(float(NEUTRAL_US),) * 2, metavar="RIGHT,LEFT",
                   help=f"the world's servos' own neutral pulses, µs (default {NEUTRAL_US},{NEUTRAL_US}): one the "
                        "firmware's trim does not match creeps")
    w.add_argument("--world-physics", metavar="PROFILE", help="the world's physics profile (name or JSON file)")
    w.add_argument("--pose-key", type=Path, metavar="FILE", help="sign the pose stream with this key file")
    w.add_argument("--reverse-servo", action="append", choices=("right", "left"), default=[],
                   help="mount this servo the other way round (a reversed servo, for bring-up tests)")
    _add_servo(w)
    w.set_defaults(func=_twin_world)
