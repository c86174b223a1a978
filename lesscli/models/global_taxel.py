"""GLOBAL with less-taxel's inputs (``global-taxel``): the fair partner of ``less-taxel``.

The paper compares a local encoder with a global one that differ only in locality. ``less-taxel`` adds a
parameter-free stiffness map to every particle, so its global partner gets the same per-step taxel features:
one recurrent state per scan (the paper's FLE and GRU over every step, poses in the phantom frame) beside one
stiffness map over the whole insert, kept by the same exact running means. The map's cells sit at the same
pitch as a particle's; the global image decoder reads both.
"""

from __future__ import annotations

import copy
import math

import torch
from torch import Tensor

from lesscli.models.taxel import TaxelParticleEncoder


class GlobalTaxelEncoder(TaxelParticleEncoder):
    """One state per scan: ``[h_gru (dim), M, Q, c]`` with one map of ``ceil(extent / pitch)^2`` cells.

    Args:
        force_dim: F = taxels x 3.
        taxel_xy_mm: (T, 2) taxel centres in the pad frame, mm.
        dim: GRU width.
        grid_extent_mm: side of the square the map covers, centred on the insert.
        map_pitch_mm: distance between map cells.
        map_contrast: as for :class:`TaxelParticleEncoder`.
        max_steps_per_particle: cap on steps (earliest kept); None = no cap.
        n_freq: wavelengths per pose coordinate.
    """

    name = "global-taxel"

    def __init__(self, force_dim: int, taxel_xy_mm, dim: int = 128, grid_extent_mm: float = 60.0,
                 map_pitch_mm: float = 2.5, map_contrast: str = "step",
                 max_steps_per_particle: int | None = None, n_freq: int = 16, **_ignored) -> None:
        if not grid_extent_mm > 0 or not map_pitch_mm > 0:
            raise ValueError("global-taxel: grid_extent_mm and map_pitch_mm must be > 0, got "
                             f"{grid_extent_mm}, {map_pitch_mm}")
        cells = max(1, math.ceil(grid_extent_mm / map_pitch_mm))
        super().__init__(force_dim, taxel_xy_mm, map_cells=cells, map_pitch_mm=map_pitch_mm,
                         map_contrast=map_contrast, dim=dim, spacing_mm=1.0, grid_extent_mm=0.0,
                         receptive_field_mm=math.inf, max_steps_per_particle=max_steps_per_particle,
                         n_freq=n_freq)
        keep = ("force_dim", "taxel_xy_mm", "dim", "map_pitch_mm", "map_contrast", "max_steps_per_particle",
                "n_freq")
        self.settings = {**{k: self.settings[k] for k in keep}, "grid_extent_mm": float(grid_extent_mm)}

    def _grid(self) -> Tensor:
        return torch.zeros(1, 2)

    def with_grid(self, extent_mm: float,
                  center_xy_mm: tuple[float, float] | None = None) -> GlobalTaxelEncoder:
        """One state whatever the phantom size (as GLOBAL): a copy of itself."""
        return copy.deepcopy(self)
