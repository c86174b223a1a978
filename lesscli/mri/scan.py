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
ORIENTATION_TOLERANCE = 1e-4        # direction cosines of one series' slices agree to this (decimal strings)
POSITION_TOLERANCE_MM = 1e-3        # slices nearer than this along the normal share a position
SPACING_TOLERANCE = 0.01            # a gap between slices off the median by more than this share is uneven


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


def _series_key(ds) -> str:
    """A series' name for ``--series``: its SeriesNumber, else its SeriesInstanceUID ("" without either)."""
    number = getattr(ds, "SeriesNumber", None)
    return str(number) if number not in (None, "") else str(getattr(ds, "SeriesInstanceUID", ""))


def _one_series(path: str, images: list, series: str | None) -> list:
    """The (file name, dataset) pairs of one series: the only one in the folder, or ``series`` (a
    SeriesNumber or SeriesInstanceUID)."""
    groups: dict[str, list] = {}
    for name, ds in images:
        groups.setdefault(str(getattr(ds, "SeriesInstanceUID", "")), []).append((name, ds))
    if series is not None:
        chosen = [g for uid, g in groups.items() if series in (uid, _series_key(g[0][1]))]
        if not chosen:
            found = ", ".join(sorted(_series_key(g[0][1]) for g in groups.values()))
            raise DataError(f"{path}: no series {series!r} in this folder (its series: {found})")
        if len(chosen) > 1:
            raise DataError(f"{path}: {len(chosen)} series numbered {series!r} in this folder; give the "
                            f"SeriesInstanceUID of one ({', '.join(sorted(uid for uid in groups if uid))})")
        return chosen[0]
    if len(groups) > 1:
        listed = "; ".join(f"{_series_key(ds)} {str(getattr(ds, 'SeriesDescription', '')).strip()!r}: {len(g)} files"
                           for g in groups.values() for _name, ds in g[:1])
        raise DataError(f"{path}: {len(groups)} series in this folder ({listed}); choose one with --series")
    return next(iter(groups.values()))


def _slice_positions(path: str, images: list) -> list:
    """``images`` sorted along the slice normal: one orientation, one image per position, evenly spaced,
    else a DataError naming the files."""
    orient = [np.asarray(ds.ImageOrientationPatient, float) for _name, ds in images]
    for (name, _ds), o in zip(images, orient):
        if np.abs(o - orient[0]).max() > ORIENTATION_TOLERANCE:
            raise DataError(f"{path}: {images[0][0]} and {name} have different orientations; one series of "
                            "parallel slices is one volume")
    normal = np.cross(orient[0][:3], orient[0][3:])
    at = np.array([float(np.asarray(ds.ImagePositionPatient, float) @ normal) for _name, ds in images])
    order = np.argsort(at, kind="stable")
    images, at = [images[i] for i in order], at[order]
    gaps = np.diff(at)
    if len(gaps) and gaps.min() <= POSITION_TOLERANCE_MM:
        k = int(np.argmin(gaps))
        raise DataError(f"{path}: {images[k][0]} and {images[k + 1][0]} lie at the same slice position "
                        f"({at[k]:.3f} mm): several images per position (echoes, phases) are not one volume")
    if len(gaps) > 1:
        step = float(np.median(gaps))
        k = int(np.argmax(np.abs(gaps - step)))
        if abs(gaps[k] - step) > max(SPACING_TOLERANCE * step, POSITION_TOLERANCE_MM):
            raise DataError(f"{path}: slices are not evenly spaced ({gaps[k]:.3f} mm between {images[k][0]} and "
                            f"{images[k + 1][0]}, {step:.3f} mm elsewhere): a slice missing?")
    return images


def _load_dicom(path: str, series: str | None = None) -> MRIScan:
    try:
        import pydicom
    except ImportError:
        raise DataError(f"{path}: reading DICOM needs pydicom (pip install 'lesscli[dicom]'), "
                        "or convert the series to NIfTI first") from None
    images = []
    for name in sorted(os.listdir(path)):
        try:
            ds = pydicom.dcmread(os.path.join(path, name))
        except (pydicom.errors.InvalidDicomError, OSError):
            LOG.debug("%s: skipping %s (not DICOM)", path, name)
            continue
        if all(hasattr(ds, key) for key in ("ImagePositionPatient", "ImageOrientationPatient", "PixelData")):
            images.append((name, ds))
    if not images:
        raise DataError(f"{path}: no DICOM images with position information in this folder")
    images = _slice_positions(path, _one_series(path, images, series))
    pixels = []
    for name, ds in images:
        try:
            pixels.append(ds.pixel_array)
        except Exception as exc:            # noqa: BLE001 - pydicom raises many kinds for undecodable data
            syntax = getattr(getattr(ds, "file_meta", None), "TransferSyntaxUID", None)
            raise DataError(f"{os.path.join(path, name)}: pixel data not decodable"
                            f"{f' ({syntax.name})' if syntax else ''}: {' '.join(str(exc).split())}") from None
    shapes = {p.shape for p in pixels}
    if len(shapes) != 1:
        raise DataError(f"{path}: slices have different sizes {sorted(shapes)}")
    vol = np.stack([p.T * float(getattr(ds, "RescaleSlope", 1.0)) + float(getattr(ds, "RescaleIntercept", 0.0))
                    for p, (_name, ds) in zip(pixels, images)], axis=2)
    return MRIScan(vol.astype(np.float32), _dicom_affine(images[0][1], images[-1][1], len(images)), path, "dicom")


def load_scan(path: str, spacing_mm=None, series: str | None = None) -> MRIScan:
    """Read a scan: NIfTI file, DICOM series folder, or .npy/.npz (with ``spacing_mm`` = (dz, dy, dx)).
    ``series``: in a DICOM folder holding several series, the one to read (SeriesNumber or
    SeriesInstanceUID).

    Raises:
        DataError: missing file, unknown format or unreadable content, naming ``path``.
    """
    if not os.path.exists(path):
        raise DataError(f"{path}: no such file or folder")
    if os.path.isdir(path):
        return _load_dicom(path, series)
    if series is not None:
        raise DataError(f"{path}: --series is for a DICOM folder; a file holds one scan")
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
