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
DEFER_BYTES = 65536                 # DICOM values this large (the pixels) are read only when used


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
    from lesscli.io.checks import declared_schema
    from lesscli.io.npfiles import read_npy, read_npz

    arrays = read_npz(path, what="numpy scan (.npz)") if path.endswith(".npz") else None
    schema = declared_schema(arrays) if arrays is not None else None
    if schema:                                          # one of the toolkit's own files, not an image
        raise DataError(f"{path}: a {schema} file, not an MRI scan (less info tells what it holds)")
    if spacing_mm is None:
        raise DataError(f"{path}: a .npy/.npz scan needs --spacing-mm dz,dy,dx")
    if arrays is not None:
        if len(arrays) != 1 and "image" not in arrays:
            raise DataError(f"{path}: expected one array (or one named 'image'), found {list(arrays)}")
        obj = arrays["image" if "image" in arrays else next(iter(arrays))]
    else:
        obj = read_npy(path, "numpy scan (.npy)")
    return MRIScan(np.asarray(obj), zyx_affine((0.0, 0.0, 0.0), spacing_mm), path, "numpy")


@dataclass
class _Image:
    """One 2D image of a DICOM series: a single-frame file, or one frame of an enhanced multi-frame file.

    Attributes:
        name: the file's name (with the frame's number in a multi-frame file), for messages.
        ds: its dataset (the series' attributes; the pixels).
        position, orientation: ImagePositionPatient (3,) and ImageOrientationPatient (6,), LPS mm.
        spacing: PixelSpacing (between rows, between columns) mm; thickness: SliceThickness mm (1 if absent).
        slope, intercept: the rescale to stored values.
        frame: the frame's index in a multi-frame file's pixels; None for a single frame.
    """

    name: str
    ds: object
    position: np.ndarray
    orientation: np.ndarray
    spacing: tuple[float, float]
    thickness: float
    slope: float
    intercept: float
    frame: int | None = None

    @property
    def normal(self) -> np.ndarray:
        return np.cross(self.orientation[:3], self.orientation[3:])

    def pixels(self) -> np.ndarray:
        """(rows, columns) stored values (pydicom keeps a multi-frame file's decoded frames)."""
        data = self.ds.pixel_array
        return data if self.frame is None or data.ndim == 2 else data[self.frame]


def _number(value, default: float) -> float:
    return default if value in (None, "") else float(value)


def _group_value(groups, sequence: str, key: str):
    """``key`` in the first of ``groups`` (functional group items, or None) whose ``sequence`` holds it."""
    for group in groups:
        if (group is not None and sequence in group and len(group[sequence].value)
            and key in group[sequence][0]):
            return group[sequence][0][key].value
    return None


def _images(name: str, ds) -> list[_Image]:
    """The images of one DICOM file: its frames, each placed by its own functional groups or the shared
    ones (enhanced multi-frame), or the file itself; none where a position, orientation or pixel spacing
    is missing (reports, presentation states)."""
    if "PerFrameFunctionalGroupsSequence" in ds and "PixelData" in ds:
        shared = ds.SharedFunctionalGroupsSequence[0] if "SharedFunctionalGroupsSequence" in ds else None
        out = []
        for k, own in enumerate(ds.PerFrameFunctionalGroupsSequence):
            groups = (own, shared)
            at = _group_value(groups, "PlanePositionSequence", "ImagePositionPatient")
            turned = _group_value(groups, "PlaneOrientationSequence", "ImageOrientationPatient")
            spacing = _group_value(groups, "PixelMeasuresSequence", "PixelSpacing")
            if at is None or turned is None or spacing is None:
                return []
            out.append(_Image(f"{name} frame {k + 1}", ds, np.asarray(at, float), np.asarray(turned, float),
                              (float(spacing[0]), float(spacing[1])),
                              _number(_group_value(groups, "PixelMeasuresSequence", "SliceThickness"), 1.0),
                              _number(_group_value(groups, "PixelValueTransformationSequence",
                                                   "RescaleSlope"), 1.0),
                              _number(_group_value(groups, "PixelValueTransformationSequence",
                                                   "RescaleIntercept"),
                                      0.0), k))
        return out
    if not all(key in ds for key in ("ImagePositionPatient", "ImageOrientationPatient", "PixelSpacing",
                                     "PixelData")):
        return []
    return [_Image(name, ds, np.asarray(ds.ImagePositionPatient, float),
                   np.asarray(ds.ImageOrientationPatient, float),
                   (float(ds.PixelSpacing[0]), float(ds.PixelSpacing[1])),
                   _number(ds.get("SliceThickness"), 1.0), _number(ds.get("RescaleSlope"), 1.0),
                   _number(ds.get("RescaleIntercept"), 0.0))]


def _dicom_affine(first: _Image, last: _Image, n: int) -> np.ndarray:
    """LPS DICOM geometry -> RAS-style affine over (column, row, slice) indices."""
    dr, dc = first.spacing
    step = (last.position - first.position) / (n - 1) if n > 1 else first.normal * first.thickness
    aff = np.eye(4)
    aff[:3, 0], aff[:3, 1] = first.orientation[:3] * dc, first.orientation[3:] * dr
    aff[:3, 2], aff[:3, 3] = step, first.position
    return np.diag([-1.0, -1.0, 1.0, 1.0]) @ aff      # LPS -> RAS


def _series_key(ds) -> str:
    """A series' name for ``--series``: its SeriesNumber, else its SeriesInstanceUID ("" without either)."""
    number = getattr(ds, "SeriesNumber", None)
    return str(number) if number not in (None, "") else str(getattr(ds, "SeriesInstanceUID", ""))


def _one_series(path: str, images: list[_Image], series: str | None) -> list[_Image]:
    """The images of one series: the only one in the folder, or ``series`` (a SeriesNumber or
    SeriesInstanceUID)."""
    groups: dict[str, list[_Image]] = {}
    for image in images:
        groups.setdefault(str(getattr(image.ds, "SeriesInstanceUID", "")), []).append(image)
    if series is not None:
        chosen = [g for uid, g in groups.items() if series in (uid, _series_key(g[0].ds))]
        if not chosen:
            found = ", ".join(sorted(_series_key(g[0].ds) for g in groups.values()))
            raise DataError(f"{path}: no series {series!r} in this folder (its series: {found})")
        if len(chosen) > 1:
            uids = sorted(str(getattr(g[0].ds, "SeriesInstanceUID", "")) for g in chosen)
            raise DataError(f"{path}: {len(chosen)} series numbered {series!r} in this folder; give the "
                            f"SeriesInstanceUID of one ({', '.join(uids)})")
        return chosen[0]
    if len(groups) > 1:
        listed = "; ".join(sorted(f"{_series_key(g[0].ds)} "
                                  f"{str(getattr(g[0].ds, 'SeriesDescription', '')).strip()!r}: {len(g)} "
                                  "images" for g in groups.values()))
        raise DataError(f"{path}: {len(groups)} series in this folder ({listed}); choose one with --series")
    return next(iter(groups.values()))


def _slice_positions(path: str, images: list[_Image]) -> list[_Image]:
    """``images`` sorted along the slice normal: one orientation, one image per position, evenly spaced,
    else a DataError naming the files."""
    for image in images:
        if np.abs(image.orientation - images[0].orientation).max() > ORIENTATION_TOLERANCE:
            raise DataError(f"{path}: {images[0].name} and {image.name} have different orientations; one "
                            "series of parallel slices is one volume")
    along = np.array([image.position for image in images]) @ images[0].normal
    order = np.argsort(along, kind="stable")
    images, at = [images[i] for i in order], along[order]
    gaps = np.diff(at)
    if len(gaps) and gaps.min() <= POSITION_TOLERANCE_MM:
        k = int(np.argmin(gaps))
        raise DataError(f"{path}: {images[k].name} and {images[k + 1].name} lie at the same slice position "
                        f"({at[k]:.3f} mm): several images per position (echoes, phases) are not one volume")
    if len(gaps) > 1:
        step = float(np.median(gaps))
        k = int(np.argmax(np.abs(gaps - step)))
        if abs(gaps[k] - step) > max(SPACING_TOLERANCE * step, POSITION_TOLERANCE_MM):
            raise DataError(f"{path}: slices are not evenly spaced ({gaps[k]:.3f} mm between "
                            f"{images[k].name} and {images[k + 1].name}, {step:.3f} mm elsewhere): a slice "
                            "missing?")
    return images


def _load_dicom(path: str, series: str | None = None) -> MRIScan:
    try:
        import pydicom
    except ImportError:
        raise DataError(f"{path}: reading DICOM needs pydicom (pip install 'less-tactile[dicom]'), "
                        "or convert the series to NIfTI first") from None
    names = sorted(os.path.relpath(os.path.join(root, f), path) for root, _dirs,
                   files in os.walk(path) for f in files)
    images = []
    for name in names:                      # large values (the pixels) read once an image is chosen
        try:
            images += _images(name, pydicom.dcmread(os.path.join(path, name), defer_size=DEFER_BYTES))
        except (pydicom.errors.InvalidDicomError, OSError):
            LOG.debug("%s: skipping %s (not DICOM)", path, name)
    if not images:
        raise DataError(f"{path}: no DICOM images with position information in this folder or under it")
    images = _slice_positions(path, _one_series(path, images, series))
    pixels = []
    for image in images:
        try:
            pixels.append(image.pixels())
        except Exception as exc:            # noqa: BLE001 - pydicom raises many kinds for undecodable data
            syntax = getattr(getattr(image.ds, "file_meta", None), "TransferSyntaxUID", None)
            named = f" ({syntax.name})" if syntax else ""
            raise DataError(f"{os.path.join(path, image.name)}: pixel data not decodable{named}: "
                            f"{' '.join(str(exc).split())}") from None
    shapes = {p.shape for p in pixels}
    if len(shapes) != 1:
        raise DataError(f"{path}: slices have different sizes {sorted(shapes)}")
    vol = np.stack([p.T * image.slope + image.intercept for p, image in zip(pixels, images)], axis=2)
    return MRIScan(vol.astype(np.float32), _dicom_affine(images[0], images[-1], len(images)), path, "dicom")


def load_scan(path: str, spacing_mm=None, series: str | None = None) -> MRIScan:
    """Read a scan: NIfTI file, DICOM series folder, or .npy/.npz (with ``spacing_mm`` = (dz, dy, dx)).
    A DICOM folder is read with its subfolders (a scanner's export of patient / study / series folders);
    ``series``: where it holds several series, the one to read (SeriesNumber or SeriesInstanceUID).

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
