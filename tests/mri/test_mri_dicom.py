"""Real DICOM series (written with pydicom) read by `less mri-label`: geometry, rescale, file order, labels."""

from __future__ import annotations

import math

import nibabel as nib
import numpy as np
import pytest
from mri_family import Case, generate

pydicom = pytest.importorskip("pydicom")

SLOPE, INTERCEPT = 0.0005, -2.0          # stored = (value - intercept) / slope fits uint16 for values in [-2, 30]
ORIGIN_LPS = np.array([-31.0, 12.5, -40.0])
DS_DECIMALS = 8                           # decimal strings hold at most 16 characters


def _cosines(angle_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Row and column directions (LPS) of an axial-oblique plane: rotated about the patient's z, then tilted."""
    a, tilt = math.radians(angle_deg), math.radians(10.0)
    row = np.array([math.cos(a), math.sin(a), 0.0])
    col = np.array([-math.sin(a) * math.cos(tilt), math.cos(a) * math.cos(tilt), math.sin(tilt)])
    return np.round(row, DS_DECIMALS), np.round(col, DS_DECIMALS)        # as written (DICOM decimal strings)


def expected_affine(spacing_mm, angle_deg: float) -> np.ndarray:
    """Index (column, row, slice) -> RAS mm, derived from the DICOM definitions (x_LPS = P + i dc row + j dr col)."""
    row, col = _cosines(angle_deg)
    normal = np.cross(row, col)
    dc, dr, ds = spacing_mm
    lps = np.eye(4)
    lps[:3, 0], lps[:3, 1], lps[:3, 2], lps[:3, 3] = row * dc, col * dr, normal * ds, ORIGIN_LPS
    return np.diag([-1.0, -1.0, 1.0, 1.0]) @ lps


def quantised(volume: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(stored uint16, the float values a reader recovers with the rescale)."""
    stored = np.clip(np.round((volume - INTERCEPT) / SLOPE), 0, 65535).astype(np.uint16)
    return stored, stored.astype(np.float64) * SLOPE + INTERCEPT


def write_series(folder, stored: np.ndarray, spacing_mm, angle_deg: float, order, names=None) -> None:
    """One file per slice; ``stored`` is (columns, rows, slices); files are written in ``order``.

    File k of the write order holds slice order[k] and is named ``names[k]`` (default IM<k>).
    """
    from pydicom.dataset import Dataset, FileMetaDataset
    from pydicom.uid import ExplicitVRLittleEndian, MRImageStorage, generate_uid

    folder.mkdir(parents=True, exist_ok=True)
    row, col = _cosines(angle_deg)
    normal = np.cross(row, col)
    dc, dr, ds_mm = spacing_mm
    series, frame = generate_uid(), generate_uid()
    for k, s in enumerate(order):
        meta = FileMetaDataset()
        meta.MediaStorageSOPClassUID, meta.MediaStorageSOPInstanceUID = MRImageStorage, generate_uid()
        meta.TransferSyntaxUID = ExplicitVRLittleEndian
        ds = Dataset()
        ds.file_meta = meta
        ds.SOPClassUID, ds.SOPInstanceUID = MRImageStorage, meta.MediaStorageSOPInstanceUID
        ds.Modality, ds.SeriesInstanceUID, ds.FrameOfReferenceUID = "MR", series, frame
        ds.InstanceNumber = int(s) + 1
        ds.ImagePositionPatient = [f"{v:.{DS_DECIMALS - 2}f}" for v in ORIGIN_LPS + s * ds_mm * normal]
        ds.ImageOrientationPatient = [f"{v:.{DS_DECIMALS}f}" for v in (*row, *col)]
        ds.PixelSpacing = [dr, dc]
        ds.SliceThickness = ds_mm
        ds.RescaleSlope, ds.RescaleIntercept = SLOPE, INTERCEPT
        pixels = np.ascontiguousarray(stored[:, :, s].T)              # rows x columns
        ds.Rows, ds.Columns = pixels.shape
        ds.SamplesPerPixel, ds.PhotometricInterpretation = 1, "MONOCHROME2"
        ds.BitsAllocated, ds.BitsStored, ds.HighBit, ds.PixelRepresentation = 16, 16, 15, 0
        ds.PixelData = pixels.astype("<u2").tobytes()
        ds.save_as(folder / (names[k] if names else f"IM{k}"), enforce_file_format=True)


@pytest.fixture(scope="module")
def scan_volume():
    """A small family volume (insert axis along the slices) as (columns, rows, slices) values and spacing."""
    vol = generate(Case(seed=5, spacing_mm=(1.1, 0.9, 1.0), inclusion_mm=(11.0,), pillar_mm=3.0,
                        pillar_height_mm=(6.0,), noise=0.04, bias=0.2))
    image = np.transpose(vol.image, (2, 1, 0)) * 20.0                  # axis 0 = columns, 2 = slices
    return image, (vol.spacing_mm[2], vol.spacing_mm[1], vol.spacing_mm[0])


def test_reader_recovers_values_geometry_and_slice_order(tmp_path):
    from lesscli.mri.scan import load_scan

    values = np.random.default_rng(0).uniform(-1.0, 25.0, (7, 6, 5))
    stored, recovered = quantised(values)
    spacing = (0.6, 0.5, 1.2)
    write_series(tmp_path / "s", stored, spacing, 30.0, order=[3, 0, 4, 1, 2], names=["b", "e", "a", "d", "c"])
    (tmp_path / "s" / "notes.txt").write_text("not DICOM")
    scan = load_scan(str(tmp_path / "s"))
    assert scan.kind == "dicom" and scan.data.shape == (7, 6, 5)
    np.testing.assert_allclose(scan.data, recovered, atol=1e-4)
    np.testing.assert_allclose(scan.affine, expected_affine(spacing, 30.0), atol=1e-5)
    np.testing.assert_allclose(scan.spacing_mm, spacing, atol=1e-5)


def test_dicom_in_any_file_order_labels_like_the_nifti(run_less, tmp_path, scan_volume):
    image, spacing = scan_volume
    stored, recovered = quantised(image)
    n = stored.shape[2]
    write_series(tmp_path / "ordered", stored, spacing, -25.0, order=list(range(n)))
    shuffled = np.random.default_rng(1).permutation(n)
    write_series(tmp_path / "shuffled", stored, spacing, -25.0, order=shuffled,
                 names=[f"{int(v):03d}.dcm" for v in np.random.default_rng(2).permutation(n)])
    nifti = nib.Nifti1Image(recovered.astype(np.float32), expected_affine(spacing, -25.0))
    nib.save(nifti, tmp_path / "scan.nii.gz")
    labels = {}
    for source in ("scan.nii.gz", "ordered", "shuffled"):
        out = f"{source.split('.')[0]}_labels.nii.gz"
        run_less("mri-label", source, "-o", out, check=True)
        img = nib.load(tmp_path / out)
        labels[source] = (np.asarray(img.dataobj), img.affine)
    ref, ref_affine = labels["scan.nii.gz"]
    assert set(np.unique(ref)) == {0, 1, 2, 3}
    for source in ("ordered", "shuffled"):
        np.testing.assert_array_equal(labels[source][0], ref)
        np.testing.assert_allclose(labels[source][1], ref_affine, atol=1e-5)
