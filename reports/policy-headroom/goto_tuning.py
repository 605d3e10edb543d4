"""How much ``goto`` itself gains from other settings, paired on the same episodes.

Every configuration drives the same ``nav-flat`` episodes (``tumblebot evaluate``'s
seeding and randomisation) on each design of the navigation cards' grid
(:data:`tumblebot.training.card_eval.NAV_GRID`, or one ``--design``); the table gives
goto's mean final R with its defaults and each configuration's paired mean difference
with a 95 % interval. A setting chosen on one seed should be checked on another.

    .venv/bin/python reports/policy-headroom/goto_tuning.py --seed 1 \\
        --config turn_tolerance=0.3,spin_steps_left=4 [--design X,Y,Z,L] [--episodes 240]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import sys
from dataclasses import fields, replace
from pathlib import Path
from typing import Any

import numpy as np

_ENV: dict[str, Any] = {}


def parse_config(text: str) -> dict[str, Any]:
    """``name=value,…`` over :class:`~tumblebot.sim.control.goto.GotoConfig`'s fields."""
    from tumblebot.sim.control.goto import GotoConfig

    known = {f.name: f.type for f in fields(GotoConfig)}
    out: dict[str, Any] = {}
    for item in text.split(","):
        name, _, value = item.partition("=")
        if name not in known or not value:
            raise argparse.ArgumentTypeError(f"{item!r}: expected NAME=VALUE with NAME one of {', '.join(known)}")
        out[name] = int(value) if known[name] in (int, "int") else float(value)
    from tumblebot.errors import TumblebotError

    try:
        replace(GotoConfig(), **out)  # GotoConfig checks the values
    except TumblebotError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from exc
    return out


def _episode(job: tuple[tuple[float, ...], int, int, list[dict[str, Any]]]) -> list[float]:
    """Final R of one episode under each configuration (the first: goto's defaults)."""
    from tumblebot.sim.control.goto import GotoConfig, GotoController
    from tumblebot.sim.evaluation.evaluate import episode_seed
    from tumblebot.sim.world.design import Design
    from tumblebot.sim.world.physics import THESIS

    design, seed, index, configs = job
    if "env" not in _ENV:  # one environment per worker, as evaluate's runner keeps
        _ENV["env"] = THESIS.make_env("nav-flat")  # the servo every card is measured under
    env = _ENV["env"]
    out = []
    for overrides in [{}, *configs]:
        obs, _ = env.reset(seed=episode_seed(seed, index),
                           options={"design": Design.from_sequence(design, allow_out_of_bounds=True)})
        goto, info = GotoController(replace(GotoConfig(), **overrides)), {}
        for step in range(env.episode_steps):
            obs, _, _, _, info = env.step(np.array(goto.act(obs, step)))
        out.append(float(info["final_R"]))
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", type=parse_config, action="append", required=True,
                        help="goto settings to compare with its defaults, NAME=VALUE,… (repeatable)")
    parser.add_argument("--design", help="one design X,Y,Z,L instead of the cards' grid")
    parser.add_argument("--episodes", type=int, default=240)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--json", type=Path, help="also write the per-design results here")
    args = parser.parse_args(argv)
    from tumblebot.errors import TumblebotError
    from tumblebot.sim.world.design import Design
    from tumblebot.training.card_eval import NAV_GRID

    try:
        designs = {args.design: Design.parse(args.design)} if args.design else NAV_GRID
    except TumblebotError as exc:
        print(f"goto_tuning: {exc}", file=sys.stderr)
        return 2
    if args.episodes < 2 or args.workers < 1:
        print("goto_tuning: need --episodes ≥ 2 and --workers ≥ 1", file=sys.stderr)
        return 2
    names = [",".join(f"{k}={v}" for k, v in c.items()) for c in args.config]
    print(f"nav-flat, {args.episodes} episodes, seed {args.seed}: goto's mean final R, and each setting's "
          "paired difference (95 % CI)")
    print(f"{'design':34s} {'goto':>6s}  " + "  ".join(f"{n:>24s}" for n in names))
    results: dict[str, Any] = {}
    with multiprocessing.get_context("forkserver").Pool(args.workers) as pool:
        for label, design in designs.items():
            jobs = [(design.as_tuple(), args.seed, i, args.config) for i in range(args.episodes)]
            R = np.array(pool.map(_episode, jobs, chunksize=8))
            diff = R[:, 1:] - R[:, :1]
            half = 1.96 * diff.std(axis=0, ddof=1) / np.sqrt(args.episodes)
            cells = [f"{d:+.3f} (±{h:.3f})" for d, h in zip(diff.mean(axis=0), half, strict=True)]
            print(f"{label:34s} {R[:, 0].mean():6.3f}  " + "  ".join(f"{c:>24s}" for c in cells), flush=True)
            results[label] = {"design": list(design.as_tuple()), "goto": float(R[:, 0].mean()),
                              "settings": {n: float(d) for n, d in zip(names, diff.mean(axis=0), strict=True)}}
    if len(results) > 1:
        means = np.mean([[r["settings"][n] for n in names] for r in results.values()], axis=0)
        print(f"{'mean over the designs':34s} {np.mean([r['goto'] for r in results.values()]):6.3f}  "
              + "  ".join(f"{m:>+24.3f}" for m in means))
    if args.json:
        args.json.write_text(json.dumps({"seed": args.seed, "episodes": args.episodes, "results": results},
                                        indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
