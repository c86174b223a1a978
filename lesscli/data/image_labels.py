"""Imaging targets from a scan set's label volumes: 3D volumes or the 2D slice through the inclusion.

A 2D target is a depth-1 volume whose origin sits at its slice, so geometry stays physical. The
default slice is the one through the inclusion centre, taken as the slice with the largest
inclusion cross-section (for a sphere the same thing; for several inclusions a well-defined
choice); a volume without inclusion uses its middle slice.
"""

from __future__ import annotations

import numpy as np
import torch

from lesscli.data.batching import ScanDataset, collate
from lesscli.errors import DataError
from lesscli.io.labels import INCLUSION, LabelVolume
from lesscli.io.scans import ScanSet
from lesscli.types import Batch, ImageGrid

AUTO_SLICE = -1          # --slice value meaning "through the inclusion centre"
GEOMETRY_ATOL_MM = 1e-6  # label grids that agree this well share one training grid


def inclusion_slice(data: np.ndarray) -> int:
    """(D, H, W) codes -> the slice with the largest inclusion area (ties: nearest the inclusion
    centroid; middle slice when there is no inclusion)."""
    area = (data == INCLUSION).sum(axis=(1, 2))
    if not area.any():
        return data.shape[0] // 2
    centroid = float((area * np.arange(len(area))).sum() / area.sum())
    best = np.flatnonzero(area == area.max())
    return int(best[np.abs(best - centroid).argmin()])


def target_volume(label: LabelVolume, dim: int, slice_index: int = AUTO_SLICE) -> LabelVolume:
    """The 3D label volume itself, or (2D) one slice of it as a depth-1 volume at that depth."""
    if dim == 3:
        return label
    k = inclusion_slice(label.data) if slice_index == AUTO_SLICE else int(slice_index)
    if not 0 <= k < label.data.shape[0]:
        raise DataError(f"{label.name or 'label volume'}: slice {k} is outside its {label.data.shape[0]} "
                        "slices")
    origin = label.origin_mm.copy()
    origin[0] += k * label.spacing_mm[0]
    return LabelVolume(label.data[k:k + 1], origin, label.spacing_mm, label.name)


def grid_of(volume: LabelVolume) -> ImageGrid:
    """The ImageGrid of a label volume."""
    return ImageGrid(tuple(int(s) for s in volume.shape), tuple(float(v) for v in volume.origin_mm),
                     tuple(float(v) for v in volume.spacing_mm))


def training_targets(scans: ScanSet, dim: int, slice_index: int = AUTO_SLICE,
                     name: str = "scan set") -> tuple[list[np.ndarray], ImageGrid]:
    """Per-scan targets (D, H, W) uint8 and their common grid; DataError names the first bad scan."""
    targets, grid = [], None
    for s in range(scans.n_scans):
        label = scans.label_of(s)
        if label is None:
            raise DataError(f"{name}: scan {s} ({scans.scan_insert[s]}) has no label volume; "
                            "imaging needs labels for every training scan")
        vol = target_volume(label, dim, slice_index)
        this = grid_of(vol)
        if grid is None:
            grid = this
        elif this.shape != grid.shape or not np.allclose(this.spacing_mm, grid.spacing_mm,
                                                         atol=GEOMETRY_ATOL_MM) \
                or not np.allclose(this.origin_mm[1:], grid.origin_mm[1:], atol=GEOMETRY_ATOL_MM):
            raise DataError(f"{name}: scan {s} has label grid {this.shape} at {this.spacing_mm} mm, but scan "
                            f"0 has {grid.shape} at {grid.spacing_mm} mm; imaging needs one label grid per "
                            "set")
        targets.append(vol.data)
    if grid is None:
        raise DataError(f"{name}: no scans to train on")
    return targets, grid


class ImageDataset(ScanDataset):
    """ScanDataset items plus ``target`` (D, H, W) long codes."""

    def __init__(self, scans: ScanSet, norm_stats: dict, targets: list[np.ndarray],
                 name: str = "scan set") -> None:
        super().__init__(scans, norm_stats, name)
        self.targets = targets

    def __getitem__(self, s: int) -> dict:
        item = super().__getitem__(s)
        item["target"] = torch.from_numpy(self.targets[s].astype(np.int64))
        return item


class ImageBatch:
    """A Batch of scans and their targets (B, D, H, W) long."""

    def __init__(self, inputs: Batch, target: torch.Tensor) -> None:
        self.inputs, self.target = inputs, target

    def to(self, device=None, dtype=None) -> ImageBatch:
        return ImageBatch(self.inputs.to(device, dtype), self.target.to(device))

    @property
    def size(self) -> int:
        return self.inputs.size


def collate_images(items: list[dict]) -> ImageBatch:
    return ImageBatch(collate(items), torch.stack([it["target"] for it in items]))
