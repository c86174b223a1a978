"""Sinusoidal positional encoding of a (centred) pad pose.

Each pose coordinate c (x, y, z in mm; roll, pitch, yaw in rad) is expanded into sin/cos at
``n_freq`` wavelengths spaced geometrically between a per-unit minimum and maximum, then a learned
linear map brings the features to the model width so they can be summed with the force MLP.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

POSE_DIM = 6
# Wavelength ranges per coordinate kind: lengths in mm, angles in rad.
LENGTH_WAVELENGTHS_MM = (1.0, 256.0)
ANGLE_WAVELENGTHS_RAD = (0.05, 4.0 * math.pi)


def pose_frequencies(n_freq: int) -> Tensor:
    """(6, n_freq) angular frequencies (rad per unit) for x, y, z (mm) and roll, pitch, yaw (rad)."""
    def geometric(lo: float, hi: float) -> Tensor:
        ratio = torch.linspace(0.0, 1.0, n_freq, dtype=torch.float64) if n_freq > 1 else torch.zeros(1)
        wavelengths = lo * (hi / lo) ** ratio
        return 2.0 * math.pi / wavelengths

    lengths = geometric(*LENGTH_WAVELENGTHS_MM)
    angles = geometric(*ANGLE_WAVELENGTHS_RAD)
    return torch.stack([lengths] * 3 + [angles] * 3).to(torch.float32)


class PoseEncoding(nn.Module):
    """Sinusoidal encoding of a pose followed by a learned linear map.

    Args:
        dim: output width.
        n_freq: wavelengths per coordinate.
    """

    def __init__(self, dim: int, n_freq: int = 16) -> None:
        super().__init__()
        self.n_freq = n_freq
        self.register_buffer("freq", pose_frequencies(n_freq), persistent=False)
        self.proj = nn.Linear(POSE_DIM * 2 * n_freq, dim)

    def features(self, pose: Tensor) -> Tensor:
        """(..., 6) pose -> (..., 6 * 2 * n_freq) raw sinusoid features (no learned part)."""
        phase = pose[..., :, None] * self.freq.to(pose.dtype)             # (..., 6, n_freq)
        return torch.cat([torch.sin(phase), torch.cos(phase)], dim=-1).flatten(-2)

    def forward(self, pose: Tensor) -> Tensor:
        """(..., 6) pose (mm, rad) -> (..., dim)."""
        return self.proj(self.features(pose))


def centre_pose(pose: Tensor, xy_mm: Tensor) -> Tensor:
    """Subtract a particle position from the x, y of poses.

    Args:
        pose: (B, P, C, 6) poses gathered per particle.
        xy_mm: (P, 2) particle positions.

    Returns:
        (B, P, C, 6) with x, y relative to each particle; z and angles unchanged.
    """
    shift = torch.zeros(xy_mm.shape[0], POSE_DIM, dtype=pose.dtype, device=pose.device)
    shift[:, :2] = xy_mm.to(pose.dtype)
    return pose - shift[None, :, None, :]
