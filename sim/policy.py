"""Running an exported policy: an ONNX file plus its model card, through onnxruntime.

Every inference outside training (evaluation, optimisation, the host) goes through
:class:`OnnxPolicy`; torch is not needed. The model card (``POLICY.json`` beside
``POLICY.onnx``) says which task and observation layout the network expects, and holds
the SHA-256 of the ONNX file; loading checks all three.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import numpy as np

from tumblebot.sim.errors import SimError

#: The observation layout every policy must declare (kept in step with env.OBS_FIELDS,
#: which a test checks; duplicated here so this module needs no PyBullet).
OBS_LAYOUT: tuple[str, ...] = ("px", "py", "pz", "qx", "qy", "qz", "qw", "cmd_right", "cmd_left")
ACTION_LAYOUT: dict[str, Any] = {"motors": ["right", "left"], "values": {"0": "reverse", "1": "stop", "2": "forward"}}


class PolicyError(SimError):
    """A policy file that is missing, corrupt, or for another task or observation layout."""


def card_path(onnx_path: Path) -> Path:
    return onnx_path.with_suffix(".json")


def sha256_of(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def bundled_policy(task: str) -> Path:
    """The policy shipped with tumblebot for ``task`` (``policies/TASK.onnx``)."""
    import tumblebot.policies

    return Path(tumblebot.policies.__file__).parent / f"{task}.onnx"


class OnnxPolicy:
    """A deterministic policy: ``act(obs) -> (right, left)`` in {0, 1, 2}.

    Args:
        path: the ``.onnx`` file; its model card must sit beside it.
        task: if given, the card's task must match.
    """

    def __init__(self, path: Path, task: str | None = None) -> None:
        path = Path(path)
        if not path.is_file():
            raise PolicyError(f"policy file {path} does not exist")
        cpath = card_path(path)
        if not cpath.is_file():
            raise PolicyError(f"policy {path} has no model card {cpath.name} beside it")
        try:
            card = json.loads(cpath.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise PolicyError(f"model card {cpath} is not valid JSON: {exc}") from None
        if not isinstance(card, dict):
            raise PolicyError(f"model card {cpath} must hold a JSON object")
        if task is not None and card.get("task") != task:
            raise PolicyError(f"policy {path} was trained for task {card.get('task')!r}, not {task!r}")
        if tuple(card.get("observation", {}).get("fields", ())) != OBS_LAYOUT:
            raise PolicyError(f"policy {path} expects observation layout {card.get('observation')!r}, "
                              f"not {list(OBS_LAYOUT)}")
        digest = sha256_of(path)
        if card.get("onnx_sha256") != digest:
            raise PolicyError(f"policy {path} does not match its model card (SHA-256 {digest[:12]}…, "
                              f"card says {str(card.get('onnx_sha256'))[:12]}…): corrupt or replaced file")
        import onnxruntime as ort

        options = ort.SessionOptions()
        options.intra_op_num_threads = 1
        options.inter_op_num_threads = 1
        try:
            self.session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own exception types
            raise PolicyError(f"policy {path} cannot be loaded by onnxruntime: {exc}") from None
        self.path = path
        self.card: dict[str, Any] = card
        self.task: str = str(card.get("task"))
        self._input = self.session.get_inputs()[0].name

    def act_batch(self, obs: np.ndarray) -> np.ndarray:
        """``(B, 9)`` observations → ``(B, 2)`` int64 actions."""
        out = self.session.run(None, {self._input: np.asarray(obs, dtype=np.float32).reshape(-1, len(OBS_LAYOUT))})
        return np.asarray(out[0], dtype=np.int64)

    def act(self, obs: np.ndarray) -> np.ndarray:
        return self.act_batch(obs)[0]
