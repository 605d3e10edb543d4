"""Exporting a trained PPO policy to one self-contained ONNX file with a model card.

The exported graph takes the policy's input ``obs`` (float32, ``(batch, N)``, dynamic
batch; N = 9 for the thesis observation, 23 for the ``context`` layout) and returns
``action`` (int64, ``(batch, 2)``): the deterministic action, i.e. the arg-max of each
motor's logits, exactly what SB3's
``predict(deterministic=True)`` returns. The feature computation
(:mod:`tumblebot.training.features`) is inside the graph.
"""

from __future__ import annotations

import json
import logging
import os
import warnings
from dataclasses import asdict
from pathlib import Path
from typing import Any

import torch
from stable_baselines3 import PPO
from torch import nn

from tumblebot.sim.control.policy import ACTION_LAYOUT, LAYOUTS, card_path, sha256_of
from tumblebot.sim.world.physics import THESIS
from tumblebot.sim.world.randomization import Randomization
from tumblebot.training.config import TrainConfig, TrainingError
from tumblebot.training.features import feature_names

OBSERVATION_NOTES = {
    "thesis": "the thesis observation",
    "context": ("the thesis observation, then the design (m), the fraction of the episode's 20 steps left "
                "and the previous step's thesis observation (the current one before the first step); "
                "OnnxPolicy builds it from the thesis observation and the design given at reset"),
    "memory": ("the context observation, then goto's motion estimates learnt from every step of the episode "
               "so far (a drive step's length in m, each spin's yaw change in rad; MotionMemory, from the "
               "commands the observations carry); OnnxPolicy builds it from the thesis observation and the "
               "design given at reset"),
    "residual": ("the memory observation, then the action goto would take now (each leg's command 0/1/2; "
                 "goto with the settings pinned in tumblebot.sim.observation.RESIDUAL_GOTO, told the action "
                 "actually taken every step): the policy learns where to deviate from the hand-written controller; "
                 "OnnxPolicy builds it from the thesis observation and the design given at reset"),
    "dual": ("the residual observation, then the action a second goto would take now (the settings pinned in "
             "tumblebot.sim.observation.DUAL_GOTO, also told the action actually taken every step): which of the "
             "two suits the body is learnt from the design; OnnxPolicy builds it from the thesis observation and the "
             "design given at reset"),
    "dual-plan": ("the fields of the dual observation, computed by two gotos with plan's steadier estimates (the "
                  "settings pinned in tumblebot.sim.observation.PLAN_GOTO and PLAN_DUAL_GOTO, the first one's "
                  "estimates in the memory fields): which of the two suits the body is learnt from the design; "
                  "OnnxPolicy builds it from the thesis observation and the design given at reset"),
    "tri-plan": ("the dual-plan observation, then the action a third goto would take now (plan's estimates with "
                 "the wider turning pinned in tumblebot.sim.observation.PLAN_SHORT_GOTO, which bodies with short "
                 "legs prefer, also told the action actually taken every step): which of the three suits the body "
                 "is learnt from the design; OnnxPolicy builds it from the thesis observation and the design "
                 "given at reset"),
}


class DeterministicActor(nn.Module):
    """The actor half of an SB3 ``ActorCriticPolicy`` with arg-max action selection."""

    def __init__(self, model: PPO) -> None:
        super().__init__()
        policy = model.policy
        self.features = policy.pi_features_extractor
        self.body = policy.mlp_extractor.policy_net
        self.head = policy.action_net
        self.nvec = [int(n) for n in model.action_space.nvec]  # type: ignore[attr-defined]
        if len(set(self.nvec)) != 1:
            raise TrainingError(f"export supports equal-sized MultiDiscrete spaces, not {self.nvec}")

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        logits = self.head(self.body(self.features(obs)))
        return torch.argmax(logits.reshape(-1, len(self.nvec), self.nvec[0]), dim=-1)


def run_folder(run: Path) -> Path | None:
    """The run folder (the one holding ``config.json``) of ``RUN`` or of a checkpoint in it.

    A checkpoint is ``RUN/latest.zip`` or ``RUN/checkpoints/step_N.zip``.
    """
    candidates = [run] if run.is_dir() else [run.parent, run.parent.parent]
    return next((c for c in candidates if (c / "config.json").is_file()), None)


def load_run(run: Path) -> tuple[PPO, TrainConfig | None, Path]:
    """Load ``RUN/latest.zip`` (or a checkpoint .zip given directly) and the run's config."""
    checkpoint = run / "latest.zip" if run.is_dir() else run
    if not checkpoint.is_file():
        raise TrainingError(f"no checkpoint at {checkpoint}")
    try:
        model = PPO.load(checkpoint, device="cpu")
    except Exception as exc:  # SB3 raises many types for a bad zip
        raise TrainingError(f"cannot load checkpoint {checkpoint}: {exc}") from None
    folder = run_folder(run)
    config = TrainConfig.load(folder / "config.json") if folder is not None else None
    return model, config, checkpoint


def wall_seconds_at(run: Path, steps: int) -> float | None:
    """Training wall time when the run reached ``steps``, from its ``episodes.csv``."""
    folder = run_folder(run)
    if folder is None or not (folder / "episodes.csv").is_file():
        return None
    import csv

    with (folder / "episodes.csv").open() as fh:
        rows = [r for r in csv.DictReader(fh) if int(r["steps"]) <= steps]
    return float(rows[-1]["wall_seconds"]) if rows else None


def export_onnx(model: PPO, path: Path) -> None:
    actor = DeterministicActor(model).eval()
    size = int(model.observation_space.shape[0])  # type: ignore[index]
    example = torch.zeros(4, size, dtype=torch.float32)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    batch = torch.export.Dim("batch", min=1)
    # The exporter logs that torchvision (not a dependency) is absent and warns about its
    # own deprecated internals; neither concerns the user.
    logging.getLogger("torch.onnx._internal.exporter._registration").setLevel(logging.ERROR)
    with torch.no_grad(), warnings.catch_warnings():
        warnings.filterwarnings("ignore", category=FutureWarning)
        torch.onnx.export(actor, (example,), str(tmp), input_names=["obs"], output_names=["action"],
                          dynamic_shapes={"obs": {0: batch}}, external_data=False, dynamo=True,
                          verbose=False)
    import onnx

    onnx.checker.check_model(onnx.load(str(tmp)), full_check=True)
    os.replace(tmp, path)


def write_card(onnx_path: Path, task: str, steps: int, config: TrainConfig | None,
               extra: dict[str, Any] | None = None) -> dict[str, Any]:
    layout = config.observation if config else "thesis"
    names = feature_names(layout)
    card: dict[str, Any] = {
        "format": "tumblebot-policy-card/1",
        "task": task,
        "observation": {"layout": layout, "fields": list(LAYOUTS[layout]), "dtype": "float32",
                        "note": OBSERVATION_NOTES[layout] + "; features inside the graph: " + ", ".join(names)},
        "action": {"name": "action", "dtype": "int64", "shape": ["batch", 2], **ACTION_LAYOUT},
        "training_steps": steps,
        "seed": config.seed if config else None,
        "training_config": asdict(config) if config else None,
        "randomization": asdict(config.randomization() if config else Randomization()),
        "servo": (config.profile() if config else THESIS).record(),
        "onnx_sha256": sha256_of(onnx_path),
    }
    if extra:
        card.update(extra)
    cpath = card_path(onnx_path)
    tmp = cpath.with_name(cpath.name + ".tmp")
    tmp.write_text(json.dumps(card, indent=2) + "\n")
    os.replace(tmp, cpath)
    return card
