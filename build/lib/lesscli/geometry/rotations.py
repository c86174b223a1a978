"""Rotations in 3D with numpy: axis rotations, quaternions, SLERP, Euler angles, rotation vectors.

The one home of these conventions for the whole package:

- A rotation matrix acts on column vectors (``x_a = R_a_b x_b``).
- Quaternions are (w, x, y, z); every function that returns one gives the unit quaternion with w >= 0.
- Rotation vectors are axis * angle, rad; the ones returned have their angle in [0, pi].
- Euler angles are the scan-set pose's (roll, pitch, yaw), rad, the convention of the published
  recordings: ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (rotations about the fixed x, then y, then z axes),
  read back as roll = atan2(R21, R22), pitch = atan2(-R20, hypot(R21, R22)), yaw = atan2(R10, R00).

Every function accepts a single item or leading batch axes.
"""

from __future__ import annotations

import math

import numpy as np

AXES = "xyz"
SMALL_ANGLE_RAD = 1e-8     # below this rotation angle, sin(t)/t and (1 - cos(t))/t^2 use their series
# Below this angle between two unit quaternions SLERP is the normalised linear blend: the two differ by
# O(angle^2) relative (< 1e-12), while arccos near 1 no longer resolves the angle itself.
SLERP_LINEAR_RAD = 1e-6


def skew(v: np.ndarray) -> np.ndarray:
    """(..., 3) vectors -> (..., 3, 3) cross-product matrices (``skew(v) @ u == cross(v, u)``)."""
    v = np.asarray(v, dtype=np.float64)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    o = np.zeros_like(x)
    return np.stack([np.stack([o, -z, y], -1), np.stack([z, o, -x], -1), np.stack([-y, x, o], -1)], -2)


def axis_rotation(axis: str, angle_rad: np.ndarray | float) -> np.ndarray:
    """Rotation by ``angle_rad`` (...,) about the coordinate axis "x", "y" or "z" -> (..., 3, 3)."""
    if len(axis) != 1 or axis not in AXES:
        raise ValueError(f"axis must be one of x, y, z, got {axis!r}")
    i = AXES.index(axis)
    j, k = (i + 1) % 3, (i + 2) % 3
    a = np.asarray(angle_rad, dtype=np.float64)
    c, s = np.cos(a), np.sin(a)
    out = np.zeros(a.shape + (3, 3))
    out[..., i, i] = 1.0
    out[..., j, j], out[..., j, k] = c, -s
    out[..., k, j], out[..., k, k] = s, c
    return out


def turn_xy(points: np.ndarray, angle_rad: float) -> np.ndarray:
    """A copy of ``points`` (..., >= 2) with x and y turned by ``angle_rad`` about z (other columns kept)."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    out = np.array(points, dtype=np.result_type(points, np.float64), copy=True)
    out[..., 0] = c * points[..., 0] - s * points[..., 1]
    out[..., 1] = s * points[..., 0] + c * points[..., 1]
    return out


def euler_to_matrix(rpy_rad: np.ndarray) -> np.ndarray:
    """(..., 3) roll, pitch, yaw rad -> (..., 3, 3) ``R = Rz(yaw) Ry(pitch) Rx(roll)``."""
    rpy = np.asarray(rpy_rad, dtype=np.float64)
    cr, sr = np.cos(rpy[..., 0]), np.sin(rpy[..., 0])
    cp, sp = np.cos(rpy[..., 1]), np.sin(rpy[..., 1])
    cy, sy = np.cos(rpy[..., 2]), np.sin(rpy[..., 2])
    return np.stack([
        np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
        np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
        np.stack([-sp, cp * sr, cp * cr], -1),
    ], -2)


def matrix_to_euler(rot: np.ndarray) -> np.ndarray:
    """(..., 3, 3) -> (..., 3) roll, pitch, yaw rad, pitch in [-pi/2, pi/2] (see the module docstring)."""
    r = np.asarray(rot, dtype=np.float64)
    roll = np.arctan2(r[..., 2, 1], r[..., 2, 2])
    pitch = np.arctan2(-r[..., 2, 0], np.hypot(r[..., 2, 1], r[..., 2, 2]))
    yaw = np.arctan2(r[..., 1, 0], r[..., 0, 0])
    return np.stack([roll, pitch, yaw], -1)


def quat_normalise(quat: np.ndarray) -> np.ndarray:
    """(..., 4) quaternions -> unit quaternions with w >= 0 (the same rotations)."""
    q = np.asarray(quat, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)


def quat_multiply(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product of (..., 4) quaternions: the rotation ``R(p) R(q)`` (q applied first)."""
    p, q = np.asarray(p, dtype=np.float64), np.asarray(q, dtype=np.float64)
    pw, pv = p[..., :1], p[..., 1:]
    qw, qv = q[..., :1], q[..., 1:]
    w = pw * qw - np.sum(pv * qv, axis=-1, keepdims=True)
    return np.concatenate([w, pw * qv + qw * pv + np.cross(pv, qv)], axis=-1)


def quat_to_matrix(quat: np.ndarray) -> np.ndarray:
    """(..., 4) quaternions (w, x, y, z), normalised here -> (..., 3, 3) rotation matrices."""
    q = np.asarray(quat, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def matrix_to_quat(rot: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 4) unit quaternions (w, x, y, z), w >= 0."""
    rot = np.asarray(rot, dtype=np.float64)
    m = rot.reshape(-1, 3, 3)
    # Each row of ``cands`` is 4 q_c q (q_c the component named by the row). The diagonal tells which
    # |q_c| is largest (4 w^2 = 1 + tr, 4 x^2 = 1 + 2 R00 - tr, ...); that row divides most stably.
    tr = np.trace(m, axis1=1, axis2=2)
    m00, m11, m22 = m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]
    d21, d02, d10 = m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0], m[:, 1, 0] - m[:, 0, 1]
    s01, s02, s12 = m[:, 0, 1] + m[:, 1, 0], m[:, 0, 2] + m[:, 2, 0], m[:, 1, 2] + m[:, 2, 1]
    cands = np.stack([
        np.stack([1 + tr, d21, d02, d10], 1),
        np.stack([d21, 1 + m00 - m11 - m22, s01, s02], 1),
        np.stack([d02, s01, 1 - m00 + m11 - m22, s12], 1),
        np.stack([d10, s02, s12, 1 - m00 - m11 + m22], 1),
    ], axis=1)
    best = np.argmax(np.stack([tr, m00, m11, m22], axis=1), axis=1)
    q = quat_normalise(cands[np.arange(m.shape[0]), best])
    return q.reshape(rot.shape[:-2] + (4,))


def rotvec_to_quat(rotvec: np.ndarray) -> np.ndarray:
    """Exponential map: (..., 3) rotation vectors, rad -> (..., 4) unit quaternions, w >= 0."""
    v = np.asarray(rotvec, dtype=np.float64)
    theta = np.linalg.norm(v, axis=-1, keepdims=True)
    small = theta < SMALL_ANGLE_RAD
    safe = np.where(small, 1.0, theta)
    half_sinc = np.where(small, 0.5 - theta**2 / 48.0, np.sin(safe / 2.0) / safe)
    return quat_normalise(np.concatenate([np.cos(theta / 2.0), v * half_sinc], axis=-1))


def quat_to_rotvec(quat: np.ndarray) -> np.ndarray:
    """Logarithm: (..., 4) unit quaternions -> (..., 3) rotation vectors with angle in [0, pi]."""
    q = np.asarray(quat, dtype=np.float64)
    q = np.where(q[..., :1] < 0, -q, q)
    vec_norm = np.linalg.norm(q[..., 1:], axis=-1)
    theta = 2.0 * np.arctan2(vec_norm, q[..., 0])
    small = vec_norm < SMALL_ANGLE_RAD
    scale = np.where(small, 2.0, theta / np.where(small, 1.0, vec_norm))
    return q[..., 1:] * scale[..., None]


def rotvec_to_matrix(rotvec: np.ndarray) -> np.ndarray:
    """Rodrigues: (..., 3) rotation vectors (axis * angle, rad) -> (..., 3, 3) rotation matrices."""
    rotvec = np.asarray(rotvec, dtype=np.float64)
    theta = np.linalg.norm(rotvec, axis=-1)[..., None, None]
    k = skew(rotvec)
    small = theta < SMALL_ANGLE_RAD
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    return np.eye(3) + a * k + b * (k @ k)


def matrix_to_rotvec(rot: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 3) rotation vectors, rad (stable near 0 and pi)."""
    return quat_to_rotvec(matrix_to_quat(rot))


def rotation_angle(rot: np.ndarray) -> np.ndarray:
    """(..., 3, 3) -> (...,) rotation angle in rad, in [0, pi]."""
    return np.linalg.norm(matrix_to_rotvec(rot), axis=-1)


def project_to_so3(mat: np.ndarray) -> np.ndarray:
    """Nearest rotation (Frobenius norm) to each (..., 3, 3) matrix, determinant +1 (no reflection)."""
    u, _, vt = np.linalg.svd(np.asarray(mat, dtype=np.float64))
    d = np.sign(np.linalg.det(u @ vt))
    fix = np.ones(u.shape[:-1])
    fix[..., -1] = d
    return (u * fix[..., None, :]) @ vt


def slerp(q0: np.ndarray, q1: np.ndarray, frac: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation along the shorter arc.

    Args:
        q0, q1: (..., 4) unit quaternions (either sign: q and -q are the same rotation).
        frac: (...,) fractions in [0, 1]; 0 gives q0, 1 gives q1's rotation.

    Returns:
        (..., 4) unit quaternions, w >= 0. Keys closer than ``SLERP_LINEAR_RAD`` are blended linearly.
    """
    q0, q1 = np.asarray(q0, np.float64), np.asarray(q1, np.float64)
    frac = np.asarray(frac, np.float64)[..., None]
    dot = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(dot < 0, -q1, q1)
    theta = np.arccos(np.abs(dot).clip(max=1.0))
    near = theta < SLERP_LINEAR_RAD
    safe = np.where(near, 1.0, np.sin(theta))
    w0 = np.where(near, 1.0 - frac, np.sin((1.0 - frac) * theta) / safe)
    w1 = np.where(near, frac, np.sin(frac * theta) / safe)
    return quat_normalise(w0 * q0 + w1 * q1)


def bracket(time_s: np.ndarray, query_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Neighbouring keys of each query time: key ``idx`` and ``idx + 1`` at fraction ``frac`` between them.

    Args:
        time_s: (n,) strictly increasing key times, s (n >= 2).
        query_s: (m,) query times; values outside [time_s[0], time_s[-1]] are clamped.

    Returns:
        idx (m,) int in [0, n - 2] and frac (m,) in [0, 1].
    """
    time_s = np.asarray(time_s, np.float64)
    query = np.clip(np.asarray(query_s, np.float64), time_s[0], time_s[-1])
    idx = np.clip(np.searchsorted(time_s, query, side="right") - 1, 0, len(time_s) - 2)
    span = time_s[idx + 1] - time_s[idx]
    frac = np.where(span > 0, (query - time_s[idx]) / np.where(span > 0, span, 1.0), 0.0)
    return idx, frac


def slerp_at(time_s: np.ndarray, rotation: np.ndarray, query_s: np.ndarray) -> np.ndarray:
    """Rotations keyed at ``time_s`` resampled at ``query_s`` by SLERP between the neighbouring keys.

    Args:
        time_s: (n,) strictly increasing key times, s (n >= 2).
        rotation: (n, 3, 3) key rotations.
        query_s: (m,) query times; values outside [time_s[0], time_s[-1]] are clamped.

    Returns:
        (m, 3, 3) rotations.
    """
    idx, frac = bracket(time_s, query_s)
    quat = matrix_to_quat(rotation)
    return quat_to_matrix(slerp(quat[idx], quat[idx + 1], frac))
