"""A tiny linear-spring contact tier for pipeline tests (not part of the package).

Each taxel is a spring whose stiffness is the series (column) stiffness of the body below it,
1/k = integral dz / E(z), so a stiff inclusion under a taxel shows as a larger force.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

COLUMN_SAMPLES = 24
CELL_AREA_MM2 = 4.7 * 4.7


@dataclass
class Result:
    force_n: np.ndarray
    indentation_mm: np.ndarray
    flags: np.ndarray


class SpringTier:
    """Column springs per taxel; ``calls`` counts solve() invocations."""

    prepared = 0

    def __init__(self, phantom, sensor, gain: float = 1.0):
        self.phantom, self.sensor, self.gain = phantom, sensor, gain
        self.txy = np.asarray(sensor["taxel_xy_mm"], dtype=np.float64)

    def prepare(self, cache_dir=None) -> None:
        SpringTier.prepared += 1

    def _stiffness(self, xy: np.ndarray) -> np.ndarray:
        """(m, 2) -> (m,) N/mm of a column spring per taxel cell."""
        z = -np.linspace(0.0, self.phantom.height_mm, COLUMN_SAMPLES)
        pts = np.concatenate([np.repeat(xy, len(z), 0), np.tile(z, len(xy))[:, None]], 1)
        e_kpa = self.phantom.youngs_kpa(pts).reshape(len(xy), len(z))
        inside = (e_kpa > 0).all(axis=1)
        compliance = (1.0 / np.where(e_kpa > 0, e_kpa * 1e-3, 1.0)).mean(axis=1) * self.phantom.height_mm
        return np.where(inside, self.gain * CELL_AREA_MM2 / compliance, 0.0)

    def _taxels(self, pose: np.ndarray):
        c, s = np.cos(pose[:, 5])[:, None], np.sin(pose[:, 5])[:, None]
        tx, ty = self.txy[None, :, 0], self.txy[None, :, 1]
        x = pose[:, :1] + c * tx - s * ty
        y = pose[:, 1:2] + s * tx + c * ty
        z = pose[:, 2:3] - np.sin(pose[:, 4:5]) * tx + np.sin(pose[:, 3:4]) * ty
        return x, y, z

    def solve(self, pose: np.ndarray) -> Result:
        x, y, z = self._taxels(np.asarray(pose, dtype=np.float64))
        k = self._stiffness(np.stack([x.ravel(), y.ravel()], 1)).reshape(x.shape)
        depth = np.maximum(-z, 0.0)
        force = np.zeros((*x.shape, 3))
        force[..., 2] = k * depth
        return Result(force, depth.max(axis=1), np.zeros(len(pose), np.int64))

    def depth_for_force(self, x_mm, y_mm, yaw_rad, target_n) -> float:
        pose = np.array([[x_mm, y_mm, -1.0, 0.0, 0.0, yaw_rad]])
        per_mm = self.solve(pose).force_n[..., 2].sum()
        return float(target_n / max(per_mm, 1e-9))
