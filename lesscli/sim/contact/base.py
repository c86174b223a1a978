"""Shared parts of the contact tiers: result type, flags, pad geometry, depth search.

Forces are newtons per taxel in the pad frame; the third axis is the normal, positive when the
surface pushes the pad back (pressing). Tiers return no shear (that is the shear effect's job).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lesscli.errors import SimulationError, did_you_mean
from lesscli.io.sensor import xela_uscu
from lesscli.sim import kinematics

FLAG_OUTSIDE_VALIDITY = 1   # tilt beyond the small-slope model (~30 deg)
FLAG_PAD_OVERHANG = 2       # part of the pressing pad lies beyond the phantom's outline
FLAG_LARGE_STRAIN = 4       # indentation beyond LARGE_STRAIN_FRACTION of the body height
LARGE_STRAIN_FRACTION = 0.3
MAX_DEPTH_FRACTION = 0.6    # depth_for_force searches depths up to this fraction of the height
DEPTH_GRID = 12             # depths evaluated per refinement round of depth_for_force
DEPTH_ROUNDS = 4
SHARE_SUB = 4               # sub-samples per side when sharing loads on a non-grid layout
GRID_TOL = 1e-6             # taxel centres this close to a regular grid use the fast cell lookup


@dataclass
class ContactResult:
    """Per-step contact output of a tier.

    Attributes:
        force_n: (n, T, 3) per-taxel force on the pad, N; normal along pad z, no shear.
        indentation_mm: (n,) max penetration of the pad into the undeformed surface (0 = no contact).
        flags: (n,) int bitmask of ``FLAG_*``.
    """

    force_n: np.ndarray
    indentation_mm: np.ndarray
    flags: np.ndarray

    @property
    def total_n(self) -> np.ndarray:
        """(n,) total normal force, N."""
        return self.force_n[..., 2].sum(axis=1)


@dataclass
class PadGeometry:
    """Taxel layout of a rigid flat pad.

    Attributes:
        taxel_xy_mm: (T, 2) taxel centres in the pad frame.
        cell_mm: side of each square taxel cell (the pitch).
        half_size_mm: (2,) half width and height of the pad face.
    """

    taxel_xy_mm: np.ndarray
    cell_mm: float
    half_size_mm: np.ndarray

    @classmethod
    def from_sensor(cls, sensor: dict | None) -> PadGeometry:
        """Read a ``lesscli.io.sensor``-style dict (default: the Xela uSCu layout)."""
        s = xela_uscu() if sensor is None else sensor
        try:
            xy = np.asarray(s["taxel_xy_mm"], dtype=np.float64).reshape(-1, 2)
            pitch = float(s["pitch_mm"])
            size = np.asarray(s.get("pad_size_mm", np.ptp(xy, axis=0) + pitch), dtype=np.float64)
        except (KeyError, TypeError, ValueError) as exc:
            raise SimulationError(f"sensor '{s.get('name', '?')}': bad taxel layout ({exc})") from None
        if xy.shape[0] == 0 or not (pitch > 0) or not np.isfinite(xy).all():
            raise SimulationError(f"sensor '{s.get('name', '?')}': needs taxels and a positive pitch")
        return cls(xy, pitch, size / 2)

    @property
    def taxels(self) -> int:
        """Number of taxels T."""
        return self.taxel_xy_mm.shape[0]

    @property
    def area_mm2(self) -> float:
        """Pad face area, mm^2."""
        return float(4 * self.half_size_mm[0] * self.half_size_mm[1])

    def under_pad(self, local_xy_mm: np.ndarray) -> np.ndarray:
        """(..., 2) pad-frame points -> (...) bool, inside the pad face."""
        return (np.abs(local_xy_mm[..., 0]) <= self.half_size_mm[0]) & \
            (np.abs(local_xy_mm[..., 1]) <= self.half_size_mm[1])

    def __post_init__(self) -> None:
        self._grid = _grid_lookup(self.taxel_xy_mm, self.cell_mm)

    def coverage(self, local_xy_mm: np.ndarray, node_mm: float) -> np.ndarray:
        """(..., 2) node positions -> (...) fraction of each node's square tributary (side ``node_mm``)
        under the pad face (separable, exact for a tributary aligned with the pad)."""
        cov = np.ones(local_xy_mm.shape[:-1])
        for axis in range(2):
            cov *= np.clip((self.half_size_mm[axis] - np.abs(local_xy_mm[..., axis])) / node_mm + 0.5, 0.0,
                           1.0)
        return cov

    def share(self, local_xy_mm: np.ndarray, node_mm: float) -> tuple[np.ndarray, np.ndarray]:
        """Split point loads with square tributaries among taxel cells by overlap area.

        The tributary (side ``node_mm``, at most one pitch) is taken aligned with the pad, so on a
        grid layout it overlaps at most 2 x 2 cells and the shares are separable. Loads beyond the
        outer cells go to the nearest edge cell. Other layouts use a 4 x 4 sub-sampling.

        Args:
            local_xy_mm: (k, 2) pad-frame load positions.
            node_mm: tributary side.

        Returns:
            cells (k, S) taxel indices and weights (k, S) summing to 1 per row.
        """
        if self._grid is None or node_mm > self.cell_mm:
            off = ((np.arange(SHARE_SUB) + 0.5) / SHARE_SUB - 0.5) * node_mm
            sub = np.stack(np.meshgrid(off, off, indexing="xy"), -1).reshape(-1, 2)
            cells = self.cell_of(local_xy_mm[:, None, :] + sub[None])
            return cells, np.full(cells.shape, 1.0 / sub.shape[0])
        origin, table = self._grid
        idx, frac = [], []
        for axis, count in ((0, table.shape[1]), (1, table.shape[0])):
            lo = local_xy_mm[:, axis] - node_mm / 2 - origin[axis]
            first = np.floor(lo / self.cell_mm)
            f0 = np.clip(((first + 1) * self.cell_mm - lo) / node_mm, 0.0, 1.0)
            idx.append(np.clip(np.stack([first, first + 1], 1), 0, count - 1).astype(np.int64))
            frac.append(np.stack([f0, 1.0 - f0], 1))
        cells = table[idx[1][:, :, None], idx[0][:, None, :]].reshape(-1, 4)
        weights = (frac[1][:, :, None] * frac[0][:, None, :]).reshape(-1, 4)
        return cells, weights

    def cell_of(self, local_xy_mm: np.ndarray) -> np.ndarray:
        """(..., 2) pad-frame points -> (...) index of the taxel cell (nearest in the max-norm)."""
        if self._grid is not None:
            origin, table = self._grid
            col = np.clip(np.floor((local_xy_mm[..., 0] - origin[0]) / self.cell_mm), 0, table.shape[1] - 1)
            row = np.clip(np.floor((local_xy_mm[..., 1] - origin[1]) / self.cell_mm), 0, table.shape[0] - 1)
            return table[row.astype(np.int64), col.astype(np.int64)]
        d = np.abs(local_xy_mm[..., None, :] - self.taxel_xy_mm).max(axis=-1)
        return np.argmin(d, axis=-1)

    def cell_samples(self, sub: int) -> tuple[np.ndarray, np.ndarray, float]:
        """A sub x sub grid of points in every taxel cell.

        Returns:
            points (T * sub^2, 2) pad-frame mm, owner (T * sub^2,) taxel index, area per point mm^2.
        """
        off = ((np.arange(sub) + 0.5) / sub - 0.5) * self.cell_mm
        grid = np.stack(np.meshgrid(off, off, indexing="xy"), -1).reshape(-1, 2)
        pts = (self.taxel_xy_mm[:, None, :] + grid[None]).reshape(-1, 2)
        owner = np.repeat(np.arange(self.taxels), sub * sub)
        return pts, owner, (self.cell_mm / sub) ** 2


def _grid_lookup(xy: np.ndarray, pitch: float) -> tuple[np.ndarray, np.ndarray] | None:
    """For taxels on a full rectangular grid of the pitch: (cell origin (2,), table (rows, cols) -> taxel)."""
    lo = xy.min(axis=0)
    ij = (xy - lo) / pitch
    if not np.allclose(ij, np.round(ij), atol=GRID_TOL):
        return None
    ij = np.round(ij).astype(np.int64)
    cols, rows = ij.max(axis=0) + 1
    if cols * rows != xy.shape[0] or len({tuple(v) for v in ij}) != xy.shape[0]:
        return None
    table = np.empty((rows, cols), dtype=np.int64)
    table[ij[:, 1], ij[:, 0]] = np.arange(xy.shape[0])
    return lo - pitch / 2, table


def check_params(tier: str, params: dict, defaults: dict) -> dict:
    """``defaults`` updated with ``params``; an unknown name raises SimulationError with the closest known
    one."""
    for key in params:
        if key not in defaults:
            raise SimulationError(f"contact '{tier}': unknown parameter '{key}'"
                                  + did_you_mean(key, defaults, f" (known: {', '.join(sorted(defaults))})"))
    return {**defaults, **params}


class ContactModel:
    """Base of the tiers: pose checks, flags, result assembly and the depth search.

    Subclasses implement ``prepare`` and ``_normal(pose) -> (force (n, T), indentation (n,),
    overhang (n,) bool)`` for poses already checked.
    """

    name = "base"

    def __init__(self, phantom, sensor: dict | None = None, **params) -> None:
        self.phantom = phantom
        self.sensor = xela_uscu() if sensor is None else sensor
        self.pad = PadGeometry.from_sensor(self.sensor)
        self.params = params
        self._prepared = False

    def prepare(self, cache_dir: str | None = None) -> None:
        """Per-phantom precompute (idempotent)."""
        raise NotImplementedError

    def _normal(self, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        raise NotImplementedError

    def solve(self, pose: np.ndarray) -> ContactResult:
        """(n, 6) pad poses -> ContactResult (see the class docstring of ContactResult).

        Raises:
            SimulationError: a pose is not finite or the pad is edge-on; a result is not finite.
        """
        if not self._prepared:
            self.prepare()
        p = kinematics.check_poses(pose, where=f"contact '{self.name}'")
        normal, indent, overhang = self._normal(p)
        bad = ~np.isfinite(normal).all(axis=1)
        if bad.any():
            i = int(np.argmax(bad))
            raise SimulationError(f"contact '{self.name}': non-finite force at sample {i}, pose "
                                  f"{p[i].tolist()}")
        flags = np.zeros(p.shape[0], dtype=np.int64)
        flags[kinematics.outside_validity(p)] |= FLAG_OUTSIDE_VALIDITY
        flags[overhang & (indent > 0)] |= FLAG_PAD_OVERHANG
        flags[indent > LARGE_STRAIN_FRACTION * float(self.phantom.height_mm)] |= FLAG_LARGE_STRAIN
        force = np.zeros((p.shape[0], self.pad.taxels, 3))
        force[..., 2] = normal
        return ContactResult(force, indent, flags)

    def corner_penetration(self, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(n, 6) -> (max penetration of pad corners inside the outline (n,), a pressing corner is outside
        (n,))."""
        corners = kinematics.pad_corners_mm(pose, 2 * self.pad.half_size_mm)
        pen = np.maximum(-corners[..., 2], 0.0)
        inside = np.asarray(self.phantom.inside_outline(corners[..., 0], corners[..., 1]), dtype=bool)
        return np.where(inside, pen, 0.0).max(axis=1), ((pen > 0) & ~inside).any(axis=1)

    def total_force_n(self, pose: np.ndarray) -> np.ndarray:
        """(n, 6) -> (n,) total normal force, N."""
        return self.solve(pose).total_n

    def depth_for_force(self, x_mm: float, y_mm: float, yaw_rad: float, target_n: float) -> float:
        """Indentation depth (mm, > 0) of a level pad at (x, y, yaw) that produces ``target_n`` newtons.

        Raises:
            SimulationError: the target is not positive, or unreachable before
                ``MAX_DEPTH_FRACTION`` of the height (e.g. the pad is off the phantom).
        """
        where = f"contact '{self.name}': depth_for_force at x={x_mm:.3f} y={y_mm:.3f} mm"
        if not (math.isfinite(target_n) and target_n > 0):
            raise SimulationError(f"{where}: target force must be positive, got {target_n}")
        lo, hi = 0.0, MAX_DEPTH_FRACTION * float(self.phantom.height_mm)
        f_lo = 0.0
        for _ in range(DEPTH_ROUNDS):
            depths = np.linspace(lo, hi, DEPTH_GRID + 1)[1:]
            pose = np.zeros((depths.size, 6))
            pose[:, 0], pose[:, 1], pose[:, 2], pose[:, 5] = x_mm, y_mm, -depths, yaw_rad
            forces = self.total_force_n(pose)
            above = np.nonzero(forces >= target_n)[0]
            if above.size == 0:
                if lo == 0.0:
                    raise SimulationError(f"{where}: {target_n:.3g} N is not reached within {hi:.1f} mm "
                                          f"(max {forces.max():.3g} N)")
                break
            j = int(above[0])
            lo, hi, f_lo, f_hi = (depths[j - 1], depths[j], forces[j - 1], forces[j]) if j else \
                (lo, depths[0], f_lo, forces[0])
        frac = (target_n - f_lo) / (f_hi - f_lo) if f_hi > f_lo else 1.0
        return float(lo + np.clip(frac, 0.0, 1.0) * (hi - lo))
