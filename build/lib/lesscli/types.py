"""Value types shared by several floors (torch only, nothing else from the package).

- :class:`ImageGrid`: where an output image lives (built by ``data``; used by ``models``, ``train``,
  ``infer``).
- :class:`Batch`: a padded batch of scans (built by ``data``, consumed by ``models``).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import torch
from torch import Tensor


@dataclass(frozen=True)
class ImageGrid:
    """Where an output image lives: (D, H, W) = (z, y, x) voxels with phantom-frame geometry.

    Attributes:
        shape: (D, H, W); a 2D image has D = 1.
        origin_mm: z, y, x of voxel [0, 0, 0]'s centre, mm.
        spacing_mm: dz, dy, dx, mm.
    """

    shape: tuple[int, int, int]
    origin_mm: tuple[float, float, float]
    spacing_mm: tuple[float, float, float]

    def pixel_of(self, xy_mm: Tensor) -> Tensor:
        """(P, 2) x, y mm -> (P, 2) fractional (column, row) pixel coordinates."""
        x = (xy_mm[:, 0] - self.origin_mm[2]) / self.spacing_mm[2]
        y = (xy_mm[:, 1] - self.origin_mm[1]) / self.spacing_mm[1]
        return torch.stack([x, y], dim=1)


@dataclass
class Batch:
    """A padded batch of scans (each scan = its trajectories concatenated in time).

    Attributes:
        pose: (B, L, 6) float32, x, y, z mm and roll, pitch, yaw rad (phantom frame), padded.
        force: (B, L, T*3) float32, normalised forces (see
            :func:`lesscli.data.batching.compute_norm_stats`), padded.
        valid: (B, L) bool, real steps (padding is False).
        scan_index: (B,) long, index of each scan in its ScanSet.
    """

    pose: Tensor
    force: Tensor
    valid: Tensor
    scan_index: Tensor

    def to(self, device: torch.device | str | None = None, dtype: torch.dtype | None = None) -> Batch:
        """Move to a device; ``dtype`` converts the float fields (pose, force)."""
        out = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if dtype is not None and value.is_floating_point():
                value = value.to(dtype)
            out[f.name] = value.to(device) if device is not None else value
        return Batch(**out)

    @property
    def size(self) -> int:
        return int(self.pose.shape[0])
