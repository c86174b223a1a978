"""Label volumes (codes 0 background, 1 insert, 2 pillar, 3 inclusion) with physical geometry.

Arrays are (D, H, W) = (z, y, x). ``origin_mm`` is the phantom-frame position (z, y, x) of the
centre of voxel [0, 0, 0]; voxel [k, i, j] sits at ``origin_mm + (k, i, j) * spacing_mm``. NIfTI
files store the array as (x, y, z) with an affine in millimetres, so they overlay in 3D Slicer.
"""

from __future__ import annotations

import hashlib
import os
import zlib
from dataclasses import dataclass, field

import numpy as np

from lesscli.errors import DataError

CLASS_NAMES = ("background", "insert", "pillar", "inclusion")
BACKGROUND, INSERT, PILLAR, INCLUSION = range(4)
N_CLASSES = len(CLASS_NAMES)


@dataclass
class LabelVolume:
    """One label volume.

    Attributes:
        data: (D, H, W) uint8 class codes.
        origin_mm: (3,) float64, z, y, x of voxel [0, 0, 0]'s centre in the phantom frame, mm.
        spacing_mm: (3,) float64, dz, dy, dx voxel size in mm (positive).
        name: free-form name (insert and orientation, MRI scan id).
    """

    data: np.ndarray
    origin_mm: np.ndarray
    spacing_mm: np.ndarray
    name: str = ""
    _hash: str | None = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.data = np.ascontiguousarray(self.data, dtype=np.uint8)
        self.origin_mm = np.asarray(self.origin_mm, dtype=np.float64).reshape(3)
        self.spacing_mm = np.asarray(self.spacing_mm, dtype=np.float64).reshape(3)

    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(self.data.shape)  # type: ignore[return-value]

    def axes_mm(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Voxel-centre coordinates along z, y, x in mm."""
        return tuple(self.origin_mm[a] + self.spacing_mm[a] * np.arange(self.data.shape[a]) for a in range(3))

    def content_hash(self) -> str:
        """Hash of codes and geometry (name excluded), for de-duplication."""
        if self._hash is None:
            h = hashlib.sha1()
            h.update(np.asarray(self.data.shape, np.int64).tobytes())
            h.update(self.origin_mm.tobytes())
            h.update(self.spacing_mm.tobytes())
            h.update(self.data.tobytes())
            self._hash = h.hexdigest()
        return self._hash

    def affine(self) -> np.ndarray:
        """4x4 NIfTI affine mapping (i=x, j=y, k=z) voxel indices to (x, y, z) mm."""
        aff = np.eye(4)
        aff[0, 0], aff[1, 1], aff[2, 2] = self.spacing_mm[2], self.spacing_mm[1], self.spacing_mm[0]
        aff[:3, 3] = self.origin_mm[2], self.origin_mm[1], self.origin_mm[0]
        return aff


def check_codes(data: np.ndarray, where: str) -> None:
    """Raise if ``data`` holds codes outside 0..3 (or values that are not whole numbers)."""
    if data.dtype.kind not in "biuf":
        raise DataError(f"{where}: label codes must be numbers 0..3, found {data.dtype} values")
    if not data.size:
        return
    if data.dtype.kind == "f" and not (np.isfinite(data).all() and (data == np.round(data)).all()):
        raise DataError(f"{where}: label codes must be whole numbers 0..3 (found NaN, inf or fractions)")
    low, high = int(data.min()), int(data.max())
    if low < 0 or high >= N_CLASSES:
        raise DataError(f"{where}: label codes must be 0..3 (background, insert, pillar, inclusion), "
                        f"found {high if high >= N_CLASSES else low}")


def save_nifti(path: str, volume: LabelVolume, dtype=np.uint8, intent: str | None = None) -> None:
    """Write ``volume`` to NIfTI at ``path`` (atomicity is the caller's: pass a temporary path); ``intent``
    a NIfTI intent name (``"label"``: the file holds label codes)."""
    import nibabel as nib

    img = nib.Nifti1Image(np.transpose(volume.data, (2, 1, 0)).astype(dtype), volume.affine())
    img.header.set_xyzt_units("mm")
    if intent:
        img.header.set_intent(intent, name="less labels")
    nib.save(img, path)


def save_nifti_array(path: str, array_zyx: np.ndarray, like: LabelVolume) -> None:
    """Write a float/int (D, H, W) array (e.g. an entropy map) on ``like``'s grid."""
    import nibabel as nib

    img = nib.Nifti1Image(np.transpose(np.asarray(array_zyx), (2, 1, 0)), like.affine())
    img.header.set_xyzt_units("mm")
    nib.save(img, path)


def load_nifti_labels(path: str) -> LabelVolume:
    """Read a label NIfTI with an axis-aligned affine (any positive voxel size)."""
    import nibabel as nib

    if not os.path.exists(path):
        raise DataError(f"{path}: no such file")
    try:
        img = nib.load(path)
        data = np.asarray(img.dataobj)
    except (OSError, ValueError, EOFError, zlib.error, nib.filebasedimages.ImageFileError) as exc:
        raise DataError(f"{path}: not a readable NIfTI file ({exc})") from None
    return labels_from_nifti(data, img.affine, path)


def labels_from_nifti(data: np.ndarray, affine: np.ndarray, path: str) -> LabelVolume:
    """The label volume of a NIfTI's array (file axis order) and affine, read from ``path`` (named in errors):
    an axis-aligned affine (any positive voxel size) and codes 0..3, else DataError."""
    if data.ndim != 3:
        raise DataError(f"{path}: expected a 3D label volume, got shape {data.shape}")
    aff = np.asarray(affine, dtype=np.float64)
    lin = aff[:3, :3]
    if not np.isfinite(aff).all():
        raise DataError(f"{path}: the affine holds NaN or inf; the file's geometry is broken")
    if not np.allclose(lin, np.diag(np.diag(lin)), atol=1e-6 * np.abs(lin).max()):
        raise DataError(f"{path}: affine is rotated or sheared; resample to an axis-aligned grid first")
    if (np.diag(lin) == 0).any():
        raise DataError(f"{path}: the affine gives a voxel size of 0 on an axis")
    flips = np.diag(lin) < 0
    for axis in np.flatnonzero(flips):
        data = np.flip(data, axis=axis)
    spacing_xyz = np.abs(np.diag(lin))
    origin_xyz = aff[:3, 3] + np.where(flips, np.diag(lin) * (np.array(data.shape) - 1), 0.0)
    check_codes(data, path)
    data = np.transpose(data, (2, 1, 0))
    return LabelVolume(data.astype(np.uint8), origin_xyz[::-1], spacing_xyz[::-1], os.path.basename(path))
