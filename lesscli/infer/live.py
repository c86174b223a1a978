"""Live input for ``less stream -``: one JSON object per line, each a (time, pose, force) sample.

A line that is not such a sample raises ValueError with a short description; the caller adds the line
number and decides whether to skip it or stop (``--on-error``).
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

from lesscli.models.encoding import POSE_DIM


@dataclass
class LiveSample:
    """One parsed live input line: time (s, None when absent), pose (6,) and raw force (F,)."""

    t: float | None
    pose: np.ndarray
    force: np.ndarray


def parse_live_line(text: str | bytes, force_dim: int, after_t: float | None = None) -> LiveSample:
    """Parse ``{"t": s, "pose": [6 numbers], "force": [[x, y, z], ...] or [F numbers]}``.

    Args:
        text: one input line (bytes are decoded as UTF-8).
        force_dim: values the model expects in 'force' (taxels x 3).
        after_t: the time of the previous accepted sample; time may not go backwards.

    Raises:
        ValueError: with a short description of what is wrong (the caller adds the line number).
    """
    if isinstance(text, bytes):
        try:
            text = text.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise ValueError(f"not UTF-8 text (byte {exc.start + 1})") from None
    try:
        obj = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"not JSON ({exc.msg} at column {exc.colno})") from None
    if not isinstance(obj, dict):
        raise ValueError("expected a JSON object with 'pose' and 'force'")  # noqa: TRY004 (a data error)
    missing = [k for k in ("pose", "force") if k not in obj]
    if missing:
        raise ValueError(f"missing {' and '.join(repr(k) for k in missing)}")
    pose = _numbers(obj["pose"], "pose").reshape(-1)
    if pose.shape[0] != POSE_DIM:
        raise ValueError(f"'pose' has {pose.shape[0]} values, expected {POSE_DIM} (x, y, z mm, roll, pitch, "
                         "yaw rad)")
    force = _numbers(obj["force"], "force").reshape(-1)
    if force.shape[0] != force_dim:
        raise ValueError(f"'force' has {force.shape[0]} values, the model expects {force_dim} (taxels x 3)")
    t = obj.get("t")
    if t is not None and (isinstance(t, bool) or not isinstance(t, (int, float)) or not np.isfinite(t)):
        raise ValueError(f"'t' must be a finite number of seconds, got {t!r}")
    if t is not None and after_t is not None and t < after_t:
        raise ValueError(f"'t' goes back in time ({t} s after {after_t} s); samples must come in time order")
    return LiveSample(None if t is None else float(t), pose, force)


def _numbers(value, key: str) -> np.ndarray:
    """A JSON (nested) list of numbers finite in float32 (the model's precision) as float64, or
    ValueError naming ``key``. JSON's true and false are not numbers (numpy would read them as 1 and 0)."""
    if _holds_bool(value):
        raise ValueError(f"'{key}' holds true/false; it must be a list of numbers")
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"'{key}' must be a list of numbers (nested lists of equal length)") from None
    if arr.dtype != np.float64 or arr.ndim == 0 or arr.size == 0 or not np.isfinite(arr).all():
        raise ValueError(f"'{key}' must be a non-empty list of finite numbers")
    if np.abs(arr).max() > np.finfo(np.float32).max:
        raise ValueError(f"'{key}' holds {np.abs(arr).max():g}, beyond float32 range (the model's precision)")
    return arr


def _holds_bool(value) -> bool:
    """Whether ``value`` is, or a (nested) list of it holds, a JSON true or false."""
    if isinstance(value, bool):
        return True
    return isinstance(value, list) and any(_holds_bool(v) for v in value)
