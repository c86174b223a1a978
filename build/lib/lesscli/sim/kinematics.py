"""Pad kinematics: pose -> pad frame, corners, taxel centres and normals (SE(3)).

A pose is (x, y, z mm, roll, pitch, yaw rad) of the pad face centre in the phantom frame. The
rotation is R = Rz(yaw) Ry(pitch) Rx(roll) (the Euler convention of the recorded data, see
:mod:`lesscli.geometry.rotations`). The pad's own z axis is its outward normal: with zero rotation
the face is parallel to the surface and z < 0 presses.

The contact tiers use a small-slope model: each surface point (x, y) meets the pad plane along
the vertical. It is valid to about ``MAX_TILT_RAD`` of tilt; beyond that results are flagged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lesscli.errors import SimulationError
from lesscli.geometry.rotations import euler_to_matrix

MAX_TILT_RAD = math.radians(30.0)     # small-slope model validity
MIN_COS_TILT = 1e-3                   # below this the pad is edge-on (or upside down): not modelled


def check_poses(pose: np.ndarray, where: str = "pose") -> np.ndarray:
    """Validate (n, 6) poses: finite, pad not edge-on; returns them as float64.

    Raises:
        SimulationError: naming the first bad sample.
    """
    p = np.asarray(pose, dtype=np.float64)
    if p.ndim == 1:
        p = p[None]
    if p.ndim != 2 or p.shape[1] != 6:
        raise SimulationError(f"{where}: expected shape (n, 6), got {np.shape(pose)}")
    bad = ~np.isfinite(p).all(axis=1)
    if bad.any():
        raise SimulationError(f"{where}: sample {int(np.argmax(bad))} is not finite: {p[bad][0].tolist()}")
    cos_tilt = euler_to_matrix(p[:, 3:])[:, 2, 2]
    bad = cos_tilt < MIN_COS_TILT
    if bad.any():
        i = int(np.argmax(bad))
        raise SimulationError(f"{where}: sample {i} tilts the pad by "
                              f"{math.degrees(math.acos(np.clip(cos_tilt[i], -1, 1))):.1f} deg; "
                              "a pad at or beyond 90 deg cannot press the surface")
    return p


def tilt_rad(pose: np.ndarray) -> np.ndarray:
    """(n, 6) -> (n,) angle between the pad normal and the phantom's z axis, rad."""
    r = euler_to_matrix(np.asarray(pose, dtype=np.float64).reshape(-1, 6)[:, 3:])
    return np.arccos(np.clip(r[:, 2, 2], -1.0, 1.0))


def outside_validity(pose: np.ndarray) -> np.ndarray:
    """(n,) bool: tilt beyond the small-slope model's validity (``MAX_TILT_RAD``)."""
    return tilt_rad(pose) > MAX_TILT_RAD + 1e-12


def pad_to_world(pose: np.ndarray, local_xy_mm: np.ndarray) -> np.ndarray:
    """Points on the pad face (pad frame x, y, z = 0) -> phantom frame.

    Args:
        pose: (n, 6).
        local_xy_mm: (k, 2) pad-frame coordinates.

    Returns:
        (n, k, 3) mm.
    """
    p = np.asarray(pose, dtype=np.float64).reshape(-1, 6)
    r = euler_to_matrix(p[:, 3:])
    loc = np.asarray(local_xy_mm, dtype=np.float64)
    u, v = loc[None, :, 0], loc[None, :, 1]
    return np.stack([p[:, None, i] + r[:, i, 0, None] * u + r[:, i, 1, None] * v for i in range(3)], axis=-1)


def taxel_centres_mm(pose: np.ndarray, sensor: dict) -> np.ndarray:
    """(n, 6) -> (n, T, 3) taxel centres in the phantom frame."""
    return pad_to_world(pose, np.asarray(sensor["taxel_xy_mm"], dtype=np.float64))


def pad_normals(pose: np.ndarray) -> np.ndarray:
    """(n, 6) -> (n, 3) outward unit normal of the pad face (pad z axis) in the phantom frame."""
    return euler_to_matrix(np.asarray(pose, dtype=np.float64).reshape(-1, 6)[:, 3:])[:, :, 2]


def pad_corners_mm(pose: np.ndarray, pad_size_mm: tuple[float, float]) -> np.ndarray:
    """(n, 6) -> (n, 4, 3) pad face corners, counter-clockwise from (-w/2, -h/2)."""
    w, h = float(pad_size_mm[0]) / 2, float(pad_size_mm[1]) / 2
    return pad_to_world(pose, np.array([[-w, -h], [w, -h], [w, h], [-w, h]]))


@dataclass
class VerticalProjection:
    """Surface points (x, y, 0) seen from the pad plane along the vertical (small-slope model).

    Attributes:
        local_xy_mm: (n, k, 2) pad-frame coordinates of the pad point above/below each surface point.
        penetration_mm: (n, k) depth of the pad plane below z = 0 there (> 0 = interpenetration).
        cos_tilt: (n,) R22, the ratio of horizontal to pad-face area.
    """

    local_xy_mm: np.ndarray
    penetration_mm: np.ndarray
    cos_tilt: np.ndarray


def project_surface(pose: np.ndarray, world_xy_mm: np.ndarray) -> VerticalProjection:
    """Project surface points vertically onto the pad plane of every pose.

    Args:
        pose: (n, 6) poses (already checked by ``check_poses``).
        world_xy_mm: (k, 2) or (n, k, 2) surface points.

    Returns:
        VerticalProjection with (n, k) arrays.
    """
    p = np.asarray(pose, dtype=np.float64).reshape(-1, 6)
    r = euler_to_matrix(p[:, 3:])
    xy = np.asarray(world_xy_mm, dtype=np.float64)
    d = (xy if xy.ndim == 3 else xy[None]) - p[:, None, :2]          # (n, k, 2)
    a = r[:, :2, :2]
    det = a[:, 0, 0] * a[:, 1, 1] - a[:, 0, 1] * a[:, 1, 0]             # = R22 for a rotation
    inv = np.stack([np.stack([a[:, 1, 1], -a[:, 0, 1]], -1), np.stack([-a[:, 1, 0], a[:, 0, 0]], -1)], 1)
    inv = inv / det[:, None, None]
    u = inv[:, 0, 0, None] * d[..., 0] + inv[:, 0, 1, None] * d[..., 1]
    v = inv[:, 1, 0, None] * d[..., 0] + inv[:, 1, 1, None] * d[..., 1]
    local = np.stack([u, v], axis=-1)
    z_pad = p[:, None, 2] + r[:, 2, 0, None] * u + r[:, 2, 1, None] * v
    return VerticalProjection(local, -z_pad, r[:, 2, 2])
