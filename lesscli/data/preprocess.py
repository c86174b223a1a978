"""Per-trajectory preprocessing of the published recordings (pure numpy, no file access).

:func:`preprocess` reproduces the published pipeline (``REFERENCE.md``, "Their per-trajectory
preprocessing"): trim to the two streams' overlap, cut at the motion onset, interpolate the robot to the
sensor's timestamps, recentre on the file's reference pose and remove the force baseline. Where the
published text leaves a convention open, the choice is fixed here and tested with hand values: the
onset uses a forward speed window (:func:`onset_index`), the baseline is the first sample after the
onset trim (the pad is still in the air), and :func:`rotate_label` turns label content
counter-clockwise-positive with x along columns and y along rows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lesscli.geometry.rotations import matrix_to_euler, slerp_at

MIN_SAMPLES = 10
ONSET_WINDOW_S = 0.2
ONSET_SPEED_MM_S = 2.0
MAX_STEPS_ROBOT = 500
MAX_STEPS_HAND_HELD = 300
M_TO_MM = 1000.0
RAW_LABEL_CODES = {0: 0, 127: 1, 200: 2, 255: 3}  # background, insert, pillar, inclusion
ORIENTATION_STEP_DEG = 45.0


@dataclass
class Stream:
    """One recorded trajectory before preprocessing (SI units, as stored).

    Attributes:
        sensor_t_s: (N,) sensor timestamps, s (any origin).
        sensor_counts: (N, T, 3) raw sensor counts.
        robot_t_s: (M,) pose timestamps, s (any origin).
        robot_pos_m: (M, 3) pad position, metres.
        robot_rot: (M, 3, 3) pad rotation matrices.
    """

    sensor_t_s: np.ndarray
    sensor_counts: np.ndarray
    robot_t_s: np.ndarray
    robot_pos_m: np.ndarray
    robot_rot: np.ndarray


@dataclass
class Processed:
    """A preprocessed trajectory: pose (n, 6) mm/rad, force (n, T, 3) counts, time_s (n,) from 0."""

    pose: np.ndarray
    force: np.ndarray
    time_s: np.ndarray


def onset_index(time_s: np.ndarray, z_mm: np.ndarray, window_s: float = ONSET_WINDOW_S,
                speed_mm_s: float = ONSET_SPEED_MM_S) -> int | None:
    """Index of the first sample whose forward-window vertical speed exceeds ``speed_mm_s``.

    Args:
        time_s: (M,) increasing timestamps, s.
        z_mm: (M,) vertical position, mm.
        window_s: window length, s; samples with ``t + window_s`` past the last timestamp are not
            considered.
        speed_mm_s: threshold on ``|z(t + window_s) - z(t)| / window_s``, mm/s.

    Returns:
        The index, or None when the pad never moves fast enough.
    """
    time_s, z_mm = np.asarray(time_s, np.float64), np.asarray(z_mm, np.float64)
    ahead = time_s + window_s
    valid = ahead <= time_s[-1] if time_s.size else np.zeros(0, bool)
    speed = np.abs(np.interp(ahead, time_s, z_mm) - z_mm) / window_s
    hits = np.flatnonzero(valid & (speed > speed_mm_s))
    return int(hits[0]) if hits.size else None


def recentre(pos: np.ndarray, rot: np.ndarray, t_ref: np.ndarray,
             rot_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Express poses in the reference frame: ``p <- (p - t_ref) R_ref``, ``R <- R_ref^T R``.

    Args:
        pos: (n, 3) positions (any length unit; ``t_ref`` in the same unit).
        rot: (n, 3, 3) rotations.
        t_ref: (3,) reference position.
        rot_ref: (3, 3) reference rotation.
    """
    rot_ref = np.asarray(rot_ref, np.float64).reshape(3, 3)
    return (np.asarray(pos, np.float64) - np.asarray(t_ref, np.float64).reshape(1, 3)) @ rot_ref, \
        np.einsum("ji,njk->nik", rot_ref, np.asarray(rot, np.float64))


def remove_baseline(force: np.ndarray) -> np.ndarray:
    """(n, T, 3) -> the same minus the first sample (float32); the first row becomes zero."""
    force = np.asarray(force, np.float64)
    return (force - force[:1]).astype(np.float32)


def calibrate_estimate(pos: np.ndarray, rot: np.ndarray, calib: dict) -> tuple[np.ndarray, np.ndarray]:
    """Tracked (hand-held) pose -> robot frame: ``p <- p r_pos^T + t_pos``, ``R <- R R_ori``."""
    r_pos = np.asarray(calib["r_pos"], np.float64).reshape(3, 3)
    t_pos = np.asarray(calib["t_pos"], np.float64).reshape(1, 3)
    r_ori = np.asarray(calib["R_ori"], np.float64).reshape(3, 3)
    return np.asarray(pos, np.float64) @ r_pos.T + t_pos, np.asarray(rot, np.float64) @ r_ori


def map_label_codes(raw: np.ndarray, where: str) -> np.ndarray:
    """Raw MRI label values 0/127/200/255 -> codes 0..3; any other value raises DataError."""
    from lesscli.errors import DataError

    raw = np.asarray(raw)
    lut = np.full(256, 255, np.uint8)
    for value, code in RAW_LABEL_CODES.items():
        lut[value] = code
    if raw.size and (raw.min() < 0 or raw.max() > 255 or np.any(raw != np.round(raw))):
        raise DataError(f"{where}: label values must be 0/127/200/255")
    codes = lut[raw.astype(np.int64)]
    if np.any(codes == 255):
        bad = sorted(set(np.unique(raw[codes == 255]).tolist()))[:5]
        raise DataError(f"{where}: unexpected label values {bad} (expected 0/127/200/255)")
    return codes


def rotate_label(data: np.ndarray, angle_deg: float) -> np.ndarray:
    """Rotate (D, H, W) label content by ``angle_deg`` about the in-plane centre, nearest neighbour.

    The plane has x along columns and y along rows; a positive angle turns x towards y. Content at
    (x, y) relative to the centre moves to ``R(angle) (x, y)``; pixels whose source falls outside
    the canvas become background (0).
    """
    data = np.asarray(data)
    _d, h, w = data.shape
    a = np.deg2rad(angle_deg)
    cy, cx = (h - 1) / 2.0, (w - 1) / 2.0
    yy, xx = np.meshgrid(np.arange(h) - cy, np.arange(w) - cx, indexing="ij")
    # inverse map: the output pixel p takes the source value at R(-a) p
    src_x = np.cos(a) * xx + np.sin(a) * yy + cx
    src_y = -np.sin(a) * xx + np.cos(a) * yy + cy
    ix, iy = np.rint(src_x).astype(np.int64), np.rint(src_y).astype(np.int64)
    inside = (ix >= 0) & (ix < w) & (iy >= 0) & (iy < h)
    out = np.zeros_like(data)
    out[:, inside] = data[:, iy[inside], ix[inside]]
    return out


def dedupe_times(time_s: np.ndarray) -> np.ndarray:
    """Boolean mask keeping the first of each run of equal timestamps."""
    keep = np.ones(time_s.shape, bool)
    keep[1:] = np.diff(time_s) > 0
    return keep


def preprocess(stream: Stream, t_ref_m: np.ndarray, rot_ref: np.ndarray,
               max_steps: int = MAX_STEPS_ROBOT) -> tuple[Processed | None, str]:
    """Preprocess one trajectory, in five steps.

    1. drop trajectories with fewer than ``MIN_SAMPLES`` sensor or robot samples; subtract each stream's
       first timestamp; keep the overlap of the two time spans;
    2. onset: the first robot sample whose vertical speed over the next ``ONSET_WINDOW_S`` exceeds
       ``ONSET_SPEED_MM_S`` (:func:`onset_index`, ``z`` linearly interpolated on the robot stream); drop
       the trajectory if there is none; drop (never truncate) trajectories with more than ``max_steps``
       sensor samples from the onset;
    3. positions interpolated linearly and rotations by SLERP to the sensor timestamps;
    4. recentring on the file's reference pose ``p <- (p - t_ref) R_ref``, ``R <- R_ref^T R``, then
       Euler angles (:func:`lesscli.geometry.rotations.matrix_to_euler`), metres -> millimetres;
    5. force baseline removal: the first kept force sample is subtracted.

    Args:
        stream: the raw recording; timestamps must already be checked non-decreasing.
        t_ref_m: (3,) reference position of the file, metres.
        rot_ref: (3, 3) reference rotation of the file.
        max_steps: trajectories with more sensor samples from onset to the end are dropped.

    Returns:
        (processed, "") or (None, reason) with reason in {"short", "no_onset", "too_long"}.
    """
    if len(stream.sensor_t_s) < MIN_SAMPLES or len(stream.robot_t_s) < MIN_SAMPLES:
        return None, "short"
    ts = np.asarray(stream.sensor_t_s, np.float64) - stream.sensor_t_s[0]
    keep = dedupe_times(np.asarray(stream.robot_t_s, np.float64))
    tr = np.asarray(stream.robot_t_s, np.float64)[keep] - stream.robot_t_s[0]
    pos_m, rot = (np.asarray(stream.robot_pos_m, np.float64)[keep],
                  np.asarray(stream.robot_rot, np.float64)[keep])
    end_s = min(ts[-1], tr[-1])
    in_robot = tr <= end_s
    if in_robot.sum() < 2:
        return None, "short"
    start = onset_index(tr[in_robot], pos_m[in_robot, 2] * M_TO_MM)
    if start is None:
        return None, "no_onset"
    sel = np.flatnonzero((ts >= tr[start]) & (ts <= end_s))
    if sel.size == 0:
        return None, "no_onset"
    if sel.size > max_steps:
        return None, "too_long"
    t = ts[sel]
    pos = np.stack([np.interp(t, tr, pos_m[:, a]) for a in range(3)], axis=1)
    rot_t = slerp_at(tr, rot, t)
    pos, rot_t = recentre(pos, rot_t, t_ref_m, rot_ref)
    pose = np.concatenate([pos * M_TO_MM, matrix_to_euler(rot_t)], axis=1).astype(np.float32)
    force = remove_baseline(np.asarray(stream.sensor_counts)[sel])
    return Processed(pose, force, t - t[0]), ""
