"""Reading MRI scans (NIfTI, DICOM series, .npy/.npz) and writing labels on the scan's own grid.

An :class:`MRIScan` keeps the array in the file's axis order with its 4x4 affine (array index -> world
x, y, z mm), so labels written back with the same affine overlay the scan in 3D Slicer / ITK-SNAP.
Arrays from .npy/.npz are (D, H, W) = (z, y, x) with ``--spacing-mm dz,dy,dx`` and origin 0.
"""

from __future__ import annotations

import logging
import os
import zlib
from dataclasses import dataclass

import numpy as np

from lesscli.errors import DataError

LOG = logging.getLogger("less")

NIFTI_SUFFIXES = (".nii", ".nii.gz")
NUMPY_SUFFIXES = (".npy", ".npz")


@dataclass
class MRIScan:
    """One scan.

    Attributes:
        data: 3D intensities in the file's axis order (validated later by the segmentation).
        affine: (4, 4) array index -> world x, y, z mm.
        path: source file or directory.
        kind: "nifti", "dicom" or "numpy".
    """

    data: np.ndarray
    affine: np.ndarray
    path: str
    kind: str

    @property
    def spacing_mm(self) -> np.ndarray:
        """(3,) voxel size per array axis, mm."""
        return np.linalg.norm(np.asarray(self.affine)[:3, :3], axis=0)


def zyx_affine(origin_mm, spacing_mm) -> np.ndarray:
    """Affine of a (z, y, x) array with origin (z, y, x) and spacing (dz, dy, dx): index -> world x, y, z."""
    aff = np.eye(4)
    aff[:3, :3] = 0.0
    aff[2, 0], aff[1, 1], aff[0, 2] = spacing_mm[0], spacing_mm[1], spacing_mm[2]
    aff[:3, 3] = origin_mm[2], origin_mm[1], origin_mm[0]
    return aff


def _load_nifti(path: str) -> MRIScan:
    import nibabel as nib

    try:
        img = nib.load(path)
        data = np.asarray(img.dataobj)
    except (OSError, ValueError, EOFError, zlib.error, nib.filebasedimages.ImageFileError) as exc:
        raise DataError(f"{path}: not a readable NIfTI file ({exc})") from None
    return MRIScan(data, np.asarray(img.affine, dtype=np.float64), path, "nifti")


def _load_numpy(path: str, spacing_mm) -> MRIScan:
    if spacing_mm is None:
        raise DataError(f"{path}: a .npy/.npz scan needs --spacing-mm dz,dy,dx")
    from lesscli.io.scans import read_npy, read_npz

    if path.endswith(".npz"):
        arrays = read_npz(path, what="numpy scan (.npz)")
        if len(arrays) != 1 and "image" not in arrays:
            raise DataError(f"{path}: expected one array (or one named 'image'), found {list(arrays)}")
        obj = arrays["image" if "image" in arrays else next(iter(arrays))]
    else:
        obj = read_npy(path, "numpy scan (.npy)")
    return MRIScan(np.asarray(obj), zyx_affine((0.0, 0.0, 0.0), spacing_mm), path, "numpy")


def _dicom_affine(first, last, n: int) -> np.ndarray:
    """LPS DICOM geometry -> RAS-style affine over (column, row, slice) indices."""
    row_dir, col_dir = np.asarray(first.ImageOrientationPatient[:3], float), np.asarray(first.ImageOrientationPatient[3:], float)
    dr, dc = (float(v) for v in first.PixelSpacing)
    p0, p1 = np.asarray(first.ImagePositionPatient, float), np.asarray(last.ImagePositionPatient, float)
    step = (p1 - p0) / (n - 1) if n > 1 else np.cross(row_dir, col_dir) * float(getattr(first, "SliceThickness", 1.0))
    aff = np.eye(4)
    aff[:3, 0], aff[:3, 1], aff[:3, 2], aff[:3, 3] = row_dir * dc, col_dir * dr, step, p0
    return np.diag([-1.0, -1.0, 1.0, 1.0]) @ aff      # LPS -> RAS


def _load_dicom(path: str) -> MRIScan:
    try:
        import pydicom
    except ImportError:
        raise DataError(f"{path}: reading DICOM needs pydicom (pip install 'lesscli[dicom]'), "
                        "or convert the series to NIfTI first") from None
    slices = []
    for name in sorted(os.listdir(path)):
        try:
            ds = pydicom.dcmread(os.path.join(path, name))
        except (pydicom.errors.InvalidDicomError, OSError):
            LOG.debug("%s: skipping %s (not DICOM)", path, name)
            continue
        if hasattr(ds, "ImagePositionPatient") and hasattr(ds, "PixelData"):
            slices.append(ds)
    if not slices:
        raise DataError(f"{path}: no DICOM images with position information in this folder")
    normal = np.cross(np.asarray(slices[0].ImageOrientationPatient[:3], float),
                      np.asarray(slices[0].ImageOrientationPatient[3:], float))
    slices.sort(key=lambda ds: float(np.asarray(ds.ImagePositionPatient, float) @ normal))
    shapes = {ds.pixel_array.shape for ds in slices}
    if len(shapes) != 1:
        raise DataError(f"{path}: slices have different sizes {sorted(shapes)}")
    vol = np.stack([ds.pixel_array.T * float(getattr(ds, "RescaleSlope", 1.0))
                    + float(getattr(ds, "RescaleIntercept", 0.0)) for ds in slices], axis=2)
    return MRIScan(vol.astype(np.float32), _dicom_affine(slices[0], slices[-1], len(slices)), path, "dicom")


def load_scan(path: str, spacing_mm=None) -> MRIScan:
    """Read a scan: NIfTI file, DICOM series folder, or .npy/.npz (with ``spacing_mm`` = (dz, dy, dx)).

    Raises:
        DataError: missing file, unknown format or unreadable content, naming ``path``.
    """
    if not os.path.exists(path):
        raise DataError(f"{path}: no such file or folder")
    if os.path.isdir(path):
        return _load_dicom(path)
    if path.endswith(NIFTI_SUFFIXES):
        scan = _load_nifti(path)
    elif path.endswith(NUMPY_SUFFIXES):
        scan = _load_numpy(path, spacing_mm)
    else:
        raise DataError(f"{path}: unknown scan format (expected .nii/.nii.gz, .npy/.npz or a DICOM folder)")
    if spacing_mm is not None and scan.kind == "nifti":
        raise DataError(f"{path}: --spacing-mm is for .npy/.npz scans; a NIfTI file carries its own affine")
    return scan


def save_labels(path: str, labels: np.ndarray, scan: MRIScan) -> None:
    """Write labels on the scan's grid, atomically: NIfTI with the scan's affine (or .npy for numpy scans).

    A numpy scan's (z, y, x) labels are written as a NIfTI (x, y, z) with an axis-aligned mm affine.
    """
    import nibabel as nib

    from lesscli.io.atomic import atomic_path

    if path.endswith(".npy"):
        with atomic_path(path, ".npy") as tmp:
            np.save(tmp, labels.astype(np.uint8))
        return
    if not path.endswith(NIFTI_SUFFIXES):
        raise DataError(f"{path}: output must end in .nii.gz, .nii or .npy")
    data, affine = labels.astype(np.uint8), np.asarray(scan.affine, dtype=np.float64)
    if scan.kind == "numpy":                     # (z, y, x) -> (x, y, z) with a diagonal affine
        data = np.transpose(data, (2, 1, 0))
        affine = affine[:, [2, 1, 0, 3]]
    img = nib.Nifti1Image(data, affine)
    img.header.set_xyzt_units("mm")
    with atomic_path(path, ".nii.gz" if path.endswith(".gz") else ".nii") as tmp:
        nib.save(img, tmp)
