"""Taxel-aware LESS (``less-taxel``): every particle also keeps a map of what its taxels felt, where.

The paper's encoder feeds the 90 forces in pad order to an MLP, so the network must learn to turn the
taxel pattern by the pad's yaw, and its GRU to average stiffness over touches; its states locate the
inclusion poorly, while the same decoder reading a local stiffness map does well
(docs/results/images-worth-trusting.md). So the state here is the paper's GRU state (same FLE, same GRU)
plus a map of log stiffness ``f / (depth + DEPTH_FLOOR_MM)`` per taxel, placed at the taxel's x-y under
the pad's pose and weighted by its indentation (z above the surface fitted from the scan's contact
onsets, :mod:`lesscli.data.surface`). The map has no parameters and its recurrence is exact, so it
streams like the GRU (:meth:`TaxelParticleEncoder.gru_step`).
"""

from __future__ import annotations

import torch
from torch import Tensor

from lesscli.models.encoders import ParticleEncoder

AXES = 3                      # force components per taxel (axis 2 normal)
CONTACT_FORCE = 0.05          # a taxel presses when its normalised normal force exceeds this
DEPTH_FLOOR_MM = 0.5          # k = f / (indentation + this): finite at zero and grazing contact
STIFFNESS_FLOOR = 1e-3        # log k is taken of max(k, this)
MAP_EPS = 1e-6                # M = S / (W + MAP_EPS): 0 where a cell has no evidence
SIGMA_PER_PITCH = 0.8         # Gaussian width of a map cell, in cell pitches
MAP_CHANNELS = 3              # per cell: mean log stiffness, mean contrast within the step, evidence
PLANE_RIDGE = 1e-3            # ridge of the per-step plane fit (map_contrast="plane")
PLANE_UNIT_MM = 10.0          # pad coordinates in this unit for the plane fit (conditioning)
MAP_CONTRASTS = ("step", "plane")


def taxel_xy(pose: Tensor, taxel_xy_mm: Tensor) -> Tensor:
    """Taxel centres projected on the x-y plane of the pose's frame.

    Args:
        pose: (..., 6) x, y, z mm, roll, pitch, yaw rad; R = Rz(yaw) Ry(pitch) Rx(roll).
        taxel_xy_mm: (T, 2) taxel centres in the pad frame.

    Returns:
        (..., T, 2) x, y mm of every taxel (relative to whatever the pose's x-y is relative to).
    """
    roll, pitch, yaw = pose[..., 3], pose[..., 4], pose[..., 5]
    cr, sr, cp, sp, cy, sy = roll.cos(), roll.sin(), pitch.cos(), pitch.sin(), yaw.cos(), yaw.sin()
    r00, r10 = cy * cp, sy * cp
    r01, r11 = cy * sp * sr - sy * cr, sy * sp * sr + cy * cr
    u, v = taxel_xy_mm[:, 0].to(pose.dtype), taxel_xy_mm[:, 1].to(pose.dtype)
    x = pose[..., 0, None] + r00[..., None] * u + r01[..., None] * v
    y = pose[..., 1, None] + r10[..., None] * u + r11[..., None] * v
    return torch.stack([x, y], dim=-1)


def map_axis(cells: int, pitch_mm: float) -> Tensor:
    """(cells,) offsets of the map's cell centres along x (and y) from the particle, mm; cells are
    row-major with y slowest."""
    return ((torch.arange(cells, dtype=torch.float64) - (cells - 1) / 2) * pitch_mm).to(torch.float32)


class TaxelParticleEncoder(ParticleEncoder):
    """LESS with a per-particle taxel stiffness map beside the GRU state (registry name ``less-taxel``).

    States are ``z = [h_gru (dim), M (m), Q (m), c (m)]`` with m = map_cells^2, so ``self.dim`` (the
    state width decoders read) is ``dim + 3 m``. Particles, receptive fields and evaluation paths are those
    of :class:`ParticleEncoder`.

    Args:
        force_dim: F = taxels x 3.
        taxel_xy_mm: (T, 2) taxel centres in the pad frame, mm.
        map_cells: cells per side of the stiffness map.
        map_pitch_mm: distance between map cells.
        map_contrast: contrast of each taxel to its step's mean (``step``) or to a plane fitted over
            the step (``plane``).
        **kwargs: :class:`ParticleEncoder` arguments (``dim`` is the GRU width).
    """

    name = "less-taxel"
    force_norm = "scale"         # uncentred, flat-fielded forces: stiffness keeps its meaning
    fle_module = "paper_fle"     # the paper's FLE feeds the GRU; :meth:`fle` adds the map beside it

    def __init__(self, force_dim: int, taxel_xy_mm, map_cells: int = 7, map_pitch_mm: float = 2.5,
                 map_contrast: str = "step", **kwargs) -> None:
        super().__init__(force_dim, **kwargs)
        xy = torch.as_tensor(taxel_xy_mm, dtype=torch.float64).reshape(-1, 2)
        if xy.shape[0] * AXES != self.force_dim:
            raise ValueError(f"less-taxel: {xy.shape[0]} taxels x {AXES} axes != {self.force_dim} force "
                             "features")
        if map_cells < 1 or not map_pitch_mm > 0:
            raise ValueError(f"less-taxel: map_cells >= 1 and map_pitch_mm > 0 needed, got {map_cells}, "
                             f"{map_pitch_mm}")
        if map_contrast not in MAP_CONTRASTS:
            raise ValueError(f"less-taxel: map_contrast must be one of {MAP_CONTRASTS}, got {map_contrast!r}")
        self.settings.update({"taxel_xy_mm": xy.tolist(), "map_cells": int(map_cells),
                              "map_pitch_mm": float(map_pitch_mm), "map_contrast": map_contrast})
        self.map_contrast = map_contrast
        self.register_buffer("taxel_xy_mm", xy.to(torch.float32), persistent=False)
        self.register_buffer("axis_mm", map_axis(map_cells, map_pitch_mm), persistent=False)
        self.sigma_mm = SIGMA_PER_PITCH * float(map_pitch_mm)
        self.gru_dim = self.dim
        self.cells = int(map_cells) ** 2
        self.dim = self.gru_dim + MAP_CHANNELS * self.cells

    def fle(self, pose: Tensor, force: Tensor) -> Tensor:
        """Step inputs ``[FLE(pose, force) (gru_dim), sum w log k, sum w contrast, sum w (m each)]``.

        Taxel t sits at ``r_t = p_xy + R(roll, pitch, yaw)[:2, :2] @ taxel_xy_t`` (mm, relative to the
        particle) and, where it presses, gives ``k_t = f_t / (depth + DEPTH_FLOOR_MM)`` weighted by its
        indentation d. With Gaussian cell weights ``w_j`` the state keeps, per cell,
        ``M_j = sum w_j d log k_t / (W_j + MAP_EPS)``, ``W_j = sum w_j d``, ``c_j = log(1 + W_j)`` and
        ``Q_j``, the same mean of log k_t less the step's trend (:meth:`_step_trend`).
        """
        taxels = self.taxel_xy_mm.shape[0]
        normal = force.unflatten(-1, (taxels, AXES))[..., 2]                     # (..., T)
        depth = torch.clamp(-pose[..., 2:3], min=0.0)
        presses = (pose[..., 2:3] < 0) & (normal > CONTACT_FORCE)
        log_k = torch.log(torch.clamp(normal / (depth + DEPTH_FLOOR_MM), min=STIFFNESS_FLOOR))
        # the Gaussian weight of a cell is separable: exp(-dx^2 / 2 s^2) exp(-dy^2 / 2 s^2)
        # (..., T, n, 2)
        d = taxel_xy(pose, self.taxel_xy_mm)[..., None, :] - self.axis_mm.to(pose.dtype)[:, None]
        wx, wy = torch.exp(-(d * d) / (2 * self.sigma_mm**2)).unbind(-1)
        pressing = presses.to(pose.dtype)
        contrast = log_k - self._step_trend(pressing, log_k)
        on = pressing * depth                                                        # weight: indentation, mm
        values = torch.stack([on * log_k, on * contrast, on], dim=-2)                     # (..., 3, T)
        maps = torch.einsum("...vt,...ty,...tx->...vyx", values, wy, wx).flatten(-3)      # (..., 3 m)
        return torch.cat([self.paper_fle(pose, force), maps], dim=-1)

    def _step_trend(self, pressing: Tensor, log_k: Tensor) -> Tensor:
        """(..., T) what a taxel's log stiffness is compared with: the mean over the step's pressing
        taxels, or the plane fitted over them (``map_contrast``: with "plane" a stiffness ramp across the
        pad, an insert's soft edge, leaves no contrast)."""
        if self.map_contrast == "step":
            return (pressing * log_k).sum(-1, keepdim=True) / pressing.sum(-1, keepdim=True).clamp(min=1.0)
        uv = self.taxel_xy_mm.to(log_k.dtype) / PLANE_UNIT_MM
        design = torch.cat([torch.ones_like(uv[:, :1]), uv], dim=-1)                     # (T, 3)
        gram = torch.einsum("...t,ti,tj->...ij", pressing, design, design) \
            + PLANE_RIDGE * torch.eye(3, dtype=log_k.dtype, device=log_k.device)
        rhs = torch.einsum("...t,ti->...i", pressing * log_k, design)
        coef = torch.linalg.solve(gram, rhs.unsqueeze(-1)).squeeze(-1)                   # (..., 3)
        return torch.einsum("...i,ti->...t", coef, design)

    def gru_step(self, x: Tensor, h: Tensor) -> Tensor:
        """One step: the GRU cell on the first ``gru_dim`` inputs, the exact map update on the rest."""
        g, m = self.gru_dim, self.cells
        h_gru = super().gru_step(x[:, :g], h[:, :g])
        s, w = x[:, g:g + 2 * m], x[:, g + 2 * m:]
        mean, weight = h[:, g:g + 2 * m], torch.expm1(h[:, g + 2 * m:])
        total = weight + w
        mean = (mean * (weight + MAP_EPS).repeat(1, 2) + s) / (total + MAP_EPS).repeat(1, 2)
        return torch.cat([h_gru, mean, torch.log1p(total)], dim=-1)

    def _run_gru(self, x: Tensor, count: Tensor) -> Tensor:
        """(N, C, gru_dim + 3m) inputs (:meth:`fle`) -> (N, C, dim) states after each real step (zeros
        past ``count``): the packed GRU on the first ``gru_dim``, running sums for the map."""
        g, m = self.gru_dim, self.cells
        h_gru = super()._run_gru(x[..., :g], count)
        real = (torch.arange(x.shape[1], device=x.device)
                < count[:, None].to(x.device))[..., None].to(x.dtype)
        s = torch.cumsum(x[..., g:g + 2 * m] * real, dim=1)
        w = torch.cumsum(x[..., g + 2 * m:] * real, dim=1)
        return torch.cat([h_gru, s / (w + MAP_EPS).repeat(1, 1, 2) * real, torch.log1p(w) * real], dim=-1)

