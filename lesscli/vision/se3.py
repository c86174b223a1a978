"""SE(3)/SO(3) algebra with numpy: rotation vectors, quaternions, SLERP, pose interpolation.

Conventions: ``T_a_b`` is a (4, 4) homogeneous transform that maps points in frame b into frame a
(``x_a = T_a_b x_b``), translations in mm. Rotation vectors are axis * angle in rad. Quaternions are
(w, x, y, z) with w >= 0. Every function accepts a single item or a leading batch axis.
"""

from __future__ import annotations

import numpy as np

SMALL_ANGLE_RAD = 1e-8     # below this, sin(theta)/theta and friends use their series
NEAR_PI_RAD = 1e-4         # within this of pi, the rotation axis is read from the symmetric part


def _skew(v: np.ndarray) -> np.ndarray:
    """(..., 3) -> (..., 3, 3) cross-product matrices."""
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    o = np.zeros_like(x)
    return np.stack([np.stack([o, -z, y], -1), np.stack([z, o, -x], -1), np.stack([-y, x, o], -1)], -2)


def rotvec_to_matrix(rotvec: np.ndarray) -> np.ndarray:
    """Rodrigues: (..., 3) rotation vectors, rad -> (..., 3, 3) rotation matrices."""
    rotvec = np.asarray(rotvec, dtype=np.float64)
    theta = np.linalg.norm(rotvec, axis=-1)[..., None, None]
    k = _skew(rotvec)
    small = theta < SMALL_ANGLE_RAD
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    return np.eye(3) + a * k + b * (k @ k)


def matrix_to_quat(rot: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 4) unit quaternions (w, x, y, z), w >= 0."""
    rot = np.asarray(rot, dtype=np.float64)
    m = rot.reshape(-1, 3, 3)
    # Shepperd's method, vectorised: build the four candidate quaternions and keep, per matrix, the one
    # whose largest component (chosen from the diagonal) makes the division stable.
    r = lambda i, j: m[:, i, j]
    tr = np.trace(m, axis1=1, axis2=2)
    diag = np.stack([tr, r(0, 0), r(1, 1), r(2, 2)], axis=1)
    cands = np.stack([
        np.stack([1 + tr, r(2, 1) - r(1, 2), r(0, 2) - r(2, 0), r(1, 0) - r(0, 1)], 1),
        np.stack([r(2, 1) - r(1, 2), 1 + r(0, 0) - r(1, 1) - r(2, 2), r(0, 1) + r(1, 0), r(0, 2) + r(2, 0)], 1),
        np.stack([r(0, 2) - r(2, 0), r(0, 1) + r(1, 0), 1 - r(0, 0) + r(1, 1) - r(2, 2), r(1, 2) + r(2, 1)], 1),
        np.stack([r(1, 0) - r(0, 1), r(0, 2) + r(2, 0), r(1, 2) + r(2, 1), 1 - r(0, 0) - r(1, 1) + r(2, 2)], 1),
    ], axis=1)
    q = cands[np.arange(m.shape[0]), np.argmax(diag, axis=1)]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 0] < 0] *= -1.0
    return q.reshape(rot.shape[:-2] + (4,))


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


def quat_to_rotvec(quat: np.ndarray) -> np.ndarray:
    """(..., 4) unit quaternions -> (..., 3) rotation vectors with angle in [0, pi]."""
    q = np.asarray(quat, dtype=np.float64)
    q = np.where(q[..., :1] < 0, -q, q)
    vec_norm = np.linalg.norm(q[..., 1:], axis=-1)
    theta = 2.0 * np.arctan2(vec_norm, q[..., 0])
    small = vec_norm < SMALL_ANGLE_RAD
    scale = np.where(small, 2.0, theta / np.where(small, 1.0, vec_norm))
    return q[..., 1:] * scale[..., None]


def matrix_to_rotvec(rot: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 3) rotation vectors, rad (stable near 0 and pi)."""
    return quat_to_rotvec(matrix_to_quat(rot))


def project_to_so3(mat: np.ndarray) -> np.ndarray:
    """Nearest rotation (Frobenius norm) to each (..., 3, 3) matrix, determinant +1 (no reflection)."""
    u, _, vt = np.linalg.svd(np.asarray(mat, dtype=np.float64))
    d = np.sign(np.linalg.det(u @ vt))
    fix = np.ones(u.shape[:-1])
    fix[..., -1] = d
    return (u * fix[..., None, :]) @ vt


def rotation_angle(rot: np.ndarray) -> np.ndarray:
    """(..., 3, 3) -> (...,) rotation angle in rad, in [0, pi]."""
    return np.linalg.norm(matrix_to_rotvec(rot), axis=-1)


def make_T(rot: np.ndarray, trans: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation and (..., 3) translation -> (..., 4, 4) homogeneous transform."""
    rot, trans = np.asarray(rot, np.float64), np.asarray(trans, np.float64)
    out = np.zeros(np.broadcast_shapes(rot.shape[:-2], trans.shape[:-1]) + (4, 4))
    out[..., :3, :3] = rot
    out[..., :3, 3] = trans
    out[..., 3, 3] = 1.0
    return out


def inv_T(T: np.ndarray) -> np.ndarray:
    """Inverse of (..., 4, 4) rigid transforms."""
    T = np.asarray(T, np.float64)
    rt = np.swapaxes(T[..., :3, :3], -1, -2)
    return make_T(rt, -(rt @ T[..., :3, 3:4])[..., 0])


def pose_to_T(position_mm: np.ndarray, rotvec_rad: np.ndarray) -> np.ndarray:
    """(..., 3) position + (..., 3) rotation vector -> (..., 4, 4)."""
    return make_T(rotvec_to_matrix(rotvec_rad), position_mm)


def T_to_pose(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(..., 4, 4) -> ((..., 3) position, (..., 3) rotation vector)."""
    T = np.asarray(T, np.float64)
    return T[..., :3, 3].copy(), matrix_to_rotvec(T[..., :3, :3])


def slerp(q0: np.ndarray, q1: np.ndarray, frac: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation of (n, 4) quaternion pairs at fractions (n,) in [0, 1]."""
    q0, q1 = np.asarray(q0, np.float64), np.asarray(q1, np.float64).copy()
    frac = np.asarray(frac, np.float64)[..., None]
    dot = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(dot < 0, -q1, q1)          # the short way round
    dot = np.abs(dot).clip(max=1.0)
    theta = np.arccos(dot)
    sin_t = np.sin(theta)
    near = sin_t < SMALL_ANGLE_RAD
    safe = np.where(near, 1.0, sin_t)
    w0 = np.where(near, 1.0 - frac, np.sin((1.0 - frac) * theta) / safe)
    w1 = np.where(near, frac, np.sin(frac * theta) / safe)
    out = w0 * q0 + w1 * q1
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


def interpolate_poses(time_s: np.ndarray, position_mm: np.ndarray, rotation: np.ndarray,
                      query_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Resample a pose stream at ``query_s``: linear in position, SLERP in rotation.

    Args:
        time_s: (n,) strictly increasing sample times, s.
        position_mm: (n, 3) positions.
        rotation: (n, 3, 3) rotation matrices.
        query_s: (m,) times inside [time_s[0], time_s[-1]] (outside values are clamped).

    Returns:
        (m, 3) positions and (m, 3, 3) rotations.
    """
    time_s = np.asarray(time_s, np.float64)
    query = np.clip(np.asarray(query_s, np.float64), time_s[0], time_s[-1])
    idx = np.clip(np.searchsorted(time_s, query, side="right") - 1, 0, len(time_s) - 2)
    span = time_s[idx + 1] - time_s[idx]
    frac = np.where(span > 0, (query - time_s[idx]) / np.where(span > 0, span, 1.0), 0.0)
    pos = np.asarray(position_mm, np.float64)
    out_pos = pos[idx] + frac[:, None] * (pos[idx + 1] - pos[idx])
    quat = matrix_to_quat(rotation)
    out_rot = quat_to_matrix(slerp(quat[idx], quat[idx + 1], frac))
    return out_pos, out_rot


def euler_to_matrix(rpy_rad: np.ndarray) -> np.ndarray:
    """(..., 3) roll, pitch, yaw -> R = Rz(yaw) Ry(pitch) Rx(roll) (the scan-set convention)."""
    rpy = np.asarray(rpy_rad, np.float64)
    cr, sr = np.cos(rpy[..., 0]), np.sin(rpy[..., 0])
    cp, sp = np.cos(rpy[..., 1]), np.sin(rpy[..., 1])
    cy, sy = np.cos(rpy[..., 2]), np.sin(rpy[..., 2])
    return np.stack([
        np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
        np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
        np.stack([-sp, cp * sr, cp * cr], -1),
    ], -2)


def matrix_to_euler(rot: np.ndarray) -> np.ndarray:
    """(..., 3, 3) -> (..., 3) roll = atan2(R21, R22), pitch = atan2(-R20, hypot(R21, R22)), yaw = atan2(R10, R00)."""
    r = np.asarray(rot, np.float64)
    roll = np.arctan2(r[..., 2, 1], r[..., 2, 2])
    pitch = np.arctan2(-r[..., 2, 0], np.hypot(r[..., 2, 1], r[..., 2, 2]))
    yaw = np.arctan2(r[..., 1, 0], r[..., 0, 0])
    return np.stack([roll, pitch, yaw], -1)
