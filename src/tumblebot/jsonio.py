"""Strict JSON for the files tumblebot writes: what any JSON reader can parse back.

Python's ``json`` writes ``NaN`` and ``Infinity`` (not JSON) and refuses NumPy's numbers;
:func:`plain` turns both into what JSON holds, and :func:`dumps` writes the result with
non-finite numbers refused, so a slip is an error here, not a file another tool rejects.
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np


def plain(o: Any) -> Any:
    """``o`` as JSON can hold it: mappings with string keys, sequences and NumPy arrays as
    lists, NumPy scalars as Python numbers, and a non-finite number (an objective nothing
    reached, a mean of no episodes) as ``None``."""
    if isinstance(o, dict):
        return {str(k): plain(v) for k, v in o.items()}
    if isinstance(o, list | tuple | np.ndarray):
        return [plain(v) for v in o]
    if isinstance(o, np.generic):
        return plain(o.item())
    if isinstance(o, float) and not math.isfinite(o):
        return None
    return o


def dumps(o: Any, indent: int | None = 2) -> str:
    """``o`` (:func:`plain`) as strict JSON text."""
    return json.dumps(plain(o), indent=indent, allow_nan=False)
