"""Particle grids in millimetres and the receptive-field gather.

A particle sits at an x-y position in the phantom frame and sees only the valid steps whose pad x-y
lies strictly inside a disc of radius ``radius_mm`` around it, in time order. The gather is a tensor
operation (a cumulative count and one scatter), vectorised over batch and particles.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

# Positions closer than this (in units of the spacing) to the grid's edge still count as inside it.
GRID_EDGE_EPS = 1e-6


def particle_grid(extent_mm: float, spacing_mm: float,
                  center_xy_mm: tuple[float, float] = (0.0, 0.0), per_axis: int | None = None) -> Tensor:
    """Particles on a square uniform grid centred on ``center_xy_mm``.

    The grid has an odd number ``n = 2 * floor(extent / (2 * spacing)) + 1`` of particles per axis,
    so it always contains its centre, and a larger extent at the same spacing contains the smaller
    grid exactly (what growing the grid for a larger phantom needs). ``per_axis`` sets n instead (any
    n, even included, as the paper's 18 x 18 grid; ``extent_mm`` is then ignored).

    Args:
        extent_mm: side of the square to cover, mm (particles lie within +-extent/2 of the centre).
        spacing_mm: distance between neighbouring particles, mm (> 0).
        center_xy_mm: grid centre x, y in mm.

    Returns:
        (P, 2) float32 x, y positions in mm, P = n * n, row-major with y slowest.
    """
    if not spacing_mm > 0 or not extent_mm >= 0:
        raise ValueError(f"particle grid needs spacing_mm > 0 and extent_mm >= 0, got {spacing_mm}, "
                         f"{extent_mm}")
    if per_axis is not None:
        if per_axis < 1:
            raise ValueError(f"particle grid needs per_axis >= 1, got {per_axis}")
        offsets = (torch.arange(per_axis, dtype=torch.float64) - (per_axis - 1) / 2) * spacing_mm
    else:
        half = math.floor(extent_mm / (2.0 * spacing_mm) + GRID_EDGE_EPS)
        offsets = torch.arange(-half, half + 1, dtype=torch.float64) * spacing_mm
    gy, gx = torch.meshgrid(offsets + center_xy_mm[1], offsets + center_xy_mm[0], indexing="ij")
    return torch.stack([gx.reshape(-1), gy.reshape(-1)], dim=1).to(torch.float32)


@dataclass
class Gathered:
    """Which steps each particle sees.

    Attributes:
        index: (B, P, C) long, step indices into the sequence, in time order; slots past ``count``
            repeat the particle's last seen step (0 when it saw nothing), so they are safe to gather.
        mask: (B, P, C) bool, slot c holds a real in-field step.
        count: (B, P) long, number of real slots (in-field steps, at most C).
        overflow: (B, P) long, in-field steps dropped because of the cap.
    """

    index: Tensor
    mask: Tensor
    count: Tensor
    overflow: Tensor

    @property
    def seen(self) -> Tensor:
        """(B, P) bool: the particle saw at least one step."""
        return self.count > 0


def in_field(xy_mm: Tensor, valid: Tensor, particles_xy_mm: Tensor, radius_mm: float) -> Tensor:
    """(B, P, L) bool: step l is valid and its x-y lies strictly within ``radius_mm`` of particle p.

    Args:
        xy_mm: (B, L, 2) pad x, y in mm.
        valid: (B, L) bool.
        particles_xy_mm: (P, 2) particle x, y in mm.
        radius_mm: receptive-field radius in mm; ``math.inf`` means every valid step.
    """
    if math.isinf(radius_mm):
        return valid[:, None, :].expand(-1, particles_xy_mm.shape[0], -1)
    d = xy_mm[:, None, :, :] - particles_xy_mm.to(xy_mm.dtype)[None, :, None, :]
    dist2 = (d * d).sum(-1)
    return valid[:, None, :] & (dist2 < radius_mm * radius_mm)


def gather_receptive_field(xy_mm: Tensor, valid: Tensor, particles_xy_mm: Tensor, radius_mm: float,
                           max_steps: int | None = None) -> Gathered:
    """Per particle, the indices of its in-field steps in time order, padded to a common length.

    When a particle has more in-field steps than ``max_steps`` its earliest ``max_steps`` are kept
    (``overflow`` counts the rest). The common length C is ``min(max_steps, largest count)`` (at
    least 1), so no memory is spent on slots no particle fills.

    Args:
        xy_mm: (B, L, 2) pad x, y in mm.
        valid: (B, L) bool, real (non-padding) steps.
        particles_xy_mm: (P, 2) particle positions in mm.
        radius_mm: receptive-field radius, mm (``math.inf`` for the whole sequence).
        max_steps: cap C on steps per particle; None for no cap.

    Returns:
        A :class:`Gathered`.
    """
    inside = in_field(xy_mm, valid, particles_xy_mm, radius_mm)          # (B, P, L)
    total = inside.sum(-1)                                               # (B, P)
    largest = int(total.max()) if total.numel() else 0
    cap = max(1, largest if max_steps is None else min(int(max_steps), largest))
    slot = torch.cumsum(inside.to(torch.long), dim=-1) - 1               # slot of each in-field step
    slot = torch.where(inside & (slot < cap), slot, torch.full_like(slot, cap))   # cap = discard slot
    steps = torch.arange(xy_mm.shape[1], device=xy_mm.device).expand_as(slot)
    b, p = slot.shape[:2]
    index = torch.zeros(b, p, cap + 1, dtype=torch.long, device=xy_mm.device)
    index.scatter_reduce_(-1, slot, steps, reduce="amax", include_self=True)
    index = index[..., :cap]
    count = total.clamp(max=cap)
    mask = torch.arange(cap, device=xy_mm.device) < count[..., None]
    last = index.gather(-1, (count - 1).clamp(min=0)[..., None])         # (B, P, 1)
    index = torch.where(mask, index, last)
    return Gathered(index=index, mask=mask, count=count, overflow=total - count)


def gather_steps(values: Tensor, index: Tensor) -> Tensor:
    """Gather per-particle step values.

    Args:
        values: (B, L, F) per-step values.
        index: (B, P, C) step indices.

    Returns:
        (B, P, C, F).
    """
    b, p, c = index.shape
    flat = index.reshape(b, p * c, 1).expand(-1, -1, values.shape[-1])
    return values.gather(1, flat).reshape(b, p, c, values.shape[-1])
