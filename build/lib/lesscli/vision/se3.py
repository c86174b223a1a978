"""SE(3) algebra with numpy: homogeneous transforms and pose-stream interpolation.

Conventions: ``T_a_b`` is a (4, 4) homogeneous transform that maps points in frame b into frame a
(``x_a = T_a_b x_b``), translations in mm. Rotations (matrices, quaternions, rotation vectors, SLERP)
live in :mod:`lesscli.geometry.rotations`. Every function accepts a single item or a leading batch axis.
"""

from __future__ import annotations

import numpy as np

from lesscli.geometry import rotations


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
    return make_T(rotations.rotvec_to_matrix(rotvec_rad), position_mm)


def T_to_pose(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(..., 4, 4) -> ((..., 3) position, (..., 3) rotation vector)."""
    T = np.asarray(T, np.float64)
    return T[..., :3, 3].copy(), rotations.matrix_to_rotvec(T[..., :3, :3])


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
    idx, frac = rotations.bracket(time_s, query_s)
    pos = np.asarray(position_mm, np.float64)
    out_pos = pos[idx] + frac[:, None] * (pos[idx + 1] - pos[idx])
    return out_pos, rotations.slerp_at(time_s, rotation, query_s)
