"""Time-stamped pose streams: reading tracked poses (JSON lines) and robot poses (.npz), resampling.

A stream is ``time_s`` (n,) increasing, ``position_mm`` (n, 3) and ``rotation`` (n, 3, 3).

Accepted files:
- ``.jsonl`` from ``less pose track``: rows with ``t``, ``position_mm``, ``rotvec_rad``; rows with
  ``"ok": false`` are skipped.
- ``.npz`` with ``time_s`` (or ``t``), ``position_mm`` and ``rotation`` (n, 3, 3) or ``rotvec_rad`` (n, 3);
  or the published robot layout ``timestamps``, ``ee_position`` (metres) and ``ee_rotation`` (n, 3, 3).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from lesscli.errors import DataError
from lesscli.geometry import rotations
from lesscli.io.npfiles import read_npz
from lesscli.io.records import read_jsonl
from lesscli.vision import se3

ROTATION_TOL = 1e-3     # |R^T R - I| beyond this is not a rotation
TIME_TOL_S = 1e-6       # timestamps this close to a span's end count as inside (text files round them)


@dataclass
class PoseStream:
    time_s: np.ndarray
    position_mm: np.ndarray
    rotation: np.ndarray

    def __len__(self) -> int:
        return int(self.time_s.shape[0])

    def select(self, keep: np.ndarray) -> PoseStream:
        return PoseStream(self.time_s[keep], self.position_mm[keep], self.rotation[keep])


def _checked(time_s, pos, rot, name: str) -> PoseStream:
    time_s, pos, rot = (np.asarray(a, np.float64) for a in (time_s, pos, rot))
    n = time_s.shape[0] if time_s.ndim == 1 else -1
    if n < 0 or pos.shape != (n, 3) or rot.shape != (n, 3, 3):
        raise DataError(f"{name}: expected times (n,), positions (n, 3), rotations (n, 3, 3); got "
                        f"{time_s.shape}, {pos.shape}, {rot.shape}")
    bad = ~(np.isfinite(time_s) & np.isfinite(pos).all(1) & np.isfinite(rot).all((1, 2)))
    if bad.any():
        raise DataError(f"{name}: NaN or inf in pose {int(np.flatnonzero(bad)[0])} ({int(bad.sum())} poses)")
    if n and np.abs(np.swapaxes(rot, 1, 2) @ rot - np.eye(3)).max() > ROTATION_TOL:
        raise DataError(f"{name}: rotations are not orthonormal")
    order = np.argsort(time_s, kind="stable")
    time_s, pos, rot = time_s[order], pos[order], rot[order]
    if n > 1 and np.any(np.diff(time_s) <= 0):
        raise DataError(f"{name}: repeated timestamps (t = {time_s[1:][np.diff(time_s) <= 0][0]})")
    return PoseStream(time_s, pos, rot)


def _from_rows(rows: list[dict], name: str) -> PoseStream:
    if any(not isinstance(r, dict) for r in rows):
        raise DataError(f"{name}: every line must be a JSON object (a pose row)")
    good = [r for r in rows if r.get("ok", True)]
    try:
        t = [float(r["t"]) for r in good]
        pos = [r["position_mm"] for r in good]
        rv = [r["rotvec_rad"] for r in good]
    except (KeyError, TypeError, ValueError) as exc:
        raise DataError(f"{name}: pose rows need 't', 'position_mm' and 'rotvec_rad' ({exc})") from None
    if not good:
        return _checked(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3, 3)), name)
    try:
        rv_arr = np.asarray(rv, np.float64)
    except (TypeError, ValueError):
        raise DataError(f"{name}: 'rotvec_rad' must hold 3 numbers per row") from None
    if rv_arr.shape != (len(good), 3):
        raise DataError(f"{name}: 'rotvec_rad' must hold 3 numbers per row")
    return _checked(t, pos, rotations.rotvec_to_matrix(rv_arr), name)


def _from_npz(arrays: dict, name: str) -> PoseStream:
    if "ee_position" in arrays:
        need = ("timestamps", "ee_rotation")
        if any(k not in arrays for k in need):
            raise DataError(f"{name}: the robot layout needs 'timestamps', 'ee_position', 'ee_rotation'")
        return _checked(arrays["timestamps"], np.asarray(arrays["ee_position"], np.float64) * 1000.0,
                        arrays["ee_rotation"], name)
    t = arrays.get("time_s", arrays.get("t"))
    if t is None or "position_mm" not in arrays:
        raise DataError(f"{name}: expected 'time_s' and 'position_mm' (plus 'rotation' or 'rotvec_rad'), "
                        f"found {', '.join(sorted(arrays)) or 'nothing'}")
    if "rotation" in arrays:
        rot = arrays["rotation"]
    elif "rotvec_rad" in arrays:
        rot = rotations.rotvec_to_matrix(np.asarray(arrays["rotvec_rad"], np.float64))
    else:
        raise DataError(f"{name}: needs 'rotation' (n, 3, 3) or 'rotvec_rad' (n, 3)")
    return _checked(t, arrays["position_mm"], rot, name)


def load_stream(path: str) -> PoseStream:
    """Read a pose stream from ``.jsonl`` (tracked poses) or ``.npz`` (robot or true poses)."""
    if path != "-" and not os.path.isfile(path):
        raise DataError(f"{path}: no such pose file")
    if path.endswith(".npz"):
        return _from_npz(read_npz(path, what="pose stream"), path)
    try:
        rows = read_jsonl(path)
    except UnicodeDecodeError:
        raise DataError(f"{path}: not a text file of JSON lines (pose rows) nor an .npz") from None
    return _from_rows(rows, path)


def overlap(est: PoseStream, ref: PoseStream, offset_s: float) -> np.ndarray:
    """(n_est,) bool: estimated samples whose time + offset lies inside the reference's time span."""
    if len(ref) < 2:
        return np.zeros(len(est), bool)
    shifted = est.time_s + offset_s
    return (shifted >= ref.time_s[0] - TIME_TOL_S) & (shifted <= ref.time_s[-1] + TIME_TOL_S)


def sync(est: PoseStream, ref: PoseStream, offset_s: float = 0.0) -> tuple[PoseStream, PoseStream]:
    """Pair each estimated sample inside the reference's span with the reference interpolated there.

    The reference sample at ``t + offset_s`` belongs to the estimated sample at ``t`` (linear position,
    SLERP rotation). Returns the kept estimated samples and the matching reference samples.
    """
    keep = overlap(est, ref, offset_s)
    kept = est.select(keep)
    pos, rot = se3.interpolate_poses(ref.time_s, ref.position_mm, ref.rotation, kept.time_s + offset_s)
    return kept, PoseStream(kept.time_s, pos, rot)
