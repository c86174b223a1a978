"""Shear: bristle (elasto-plastic stick-slip) friction per taxel, plus Poisson shear under pressing.

Each taxel in contact (normal force > ``contact_n``) carries a tangential bristle force: sliding the
pad by du (pad frame) loads it by -k du (``stiffness_n_per_mm``); it saturates at the Coulomb limit
mu * F_n, where the taxel slips. Out of contact the bristle relaxes to zero. Pressing also pulls the
skin outwards under the pad: a radial shear of ``radial`` * F_n * r / r_max at each taxel.
Forces are on the pad, pad frame (x, y tangential; z normal).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from lesscli.errors import DataError
from lesscli.sim.state import SimState, Stage

DEFAULTS = {"mu": 0.8, "stiffness_n_per_mm": 0.3, "radial": 0.05, "contact_n": 1e-4}
MU_RANGE = (0.0, 3.0)


def validate(params: dict, where: str) -> None:
    if not MU_RANGE[0] <= params["mu"] <= MU_RANGE[1] or params["stiffness_n_per_mm"] < 0:
        raise DataError(f"{where}: mu must lie in {list(MU_RANGE)} and stiffness_n_per_mm >= 0")


def pad_frame_steps(pose: np.ndarray) -> np.ndarray:
    """(n, 2) in-plane pad displacement since the previous step, in the pad frame (first step 0)."""
    d = np.diff(pose[:, :2], axis=0, prepend=pose[:1, :2])
    c, s = np.cos(pose[:, 5]), np.sin(pose[:, 5])
    return np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], 1)


def bristle(normal_n: np.ndarray, du_mm: np.ndarray, params: dict) -> np.ndarray:
    """Tangential forces (L, T, 2) for normal forces (L, T) and pad steps (L, 2) of one trajectory."""
    out = np.zeros((*normal_n.shape, 2))
    ft = np.zeros((normal_n.shape[1], 2))
    k, mu = params["stiffness_n_per_mm"], params["mu"]
    for n in range(normal_n.shape[0]):
        fn = normal_n[n]
        ft = ft - k * du_mm[n]
        limit = mu * np.maximum(fn, 0.0)
        mag = np.linalg.norm(ft, axis=1)
        scale = np.where(mag > limit, limit / np.maximum(mag, 1e-300), 1.0)
        ft = np.where((fn > params["contact_n"])[:, None], ft * scale[:, None], 0.0)
        out[n] = ft
    return out


def _shear(state: SimState, params: dict, rng: np.random.Generator) -> SimState:
    force = np.array(state.force, copy=True)
    du = pad_frame_steps(state.pose_true)
    txy = state.taxel_xy_mm
    radial_dir = txy / max(np.linalg.norm(txy, axis=1).max(), 1e-9)
    for r in range(len(state.offsets) - 1):
        sl = slice(state.offsets[r], state.offsets[r + 1])
        fn = state.force[sl, :, 2]
        du_r = du[sl].copy()
        du_r[0] = 0.0
        force[sl, :, :2] += (bristle(fn, du_r, params) + params["radial"] * np.maximum(fn, 0)[..., None]
                             * radial_dir)
    return replace(state, force=force)


def stages(params: dict) -> tuple[Stage, ...]:
    return (Stage("shear", "shear", "force", ("force", "pose_true", "offsets", "sensor"), ("force",),
                  _shear, params),)
