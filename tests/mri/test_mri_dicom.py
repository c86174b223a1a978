"""Real DICOM series (written with pydicom) read by `less mri-label`: geometry, rescale, file order, labels;
enhanced multi-frame files; folders of several series; series that are not one volume."""

from __future__ import annotations

import math
import re

import nibabel as nib
import numpy as np
import pytest
from mri_family import Case, generate

pydicom = pytest.importorskip("pydicom")

# stored = (value - intercept) / slope fits uint16 for values in [-2, 30]
SLOPE, INTERCEPT = 0.0005, -2.0
ORIGIN_LPS = np.array([-31.0, 12.5, -40.0])
DS_DECIMALS = 8                           # decimal strings hold at most 16 characters


def _cosines(angle_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Row and column directions (LPS) of an axial-oblique plane: rotated about the patient's z, then
    tilted."""
    a, tilt = math.radians(angle_deg), math.radians(10.0)
    row = np.array([math.cos(a), math.sin(a), 0.0])
    col = np.array([-math.sin(a) * math.cos(tilt), math.cos(a) * math.cos(tilt), math.sin(tilt)])
    return np.round(row, DS_DECIMALS), np.round(col, DS_DECIMALS)        # as written (DICOM decimal strings)


def expected_affine(spacing_mm, angle_deg: float) -> np.ndarray:
    """Index (column, row, slice) -> RAS mm, derived from the DICOM definitions (x_LPS = P + i dc row + j dr
    col)."""
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


def _image_dataset(sop_class: str, pixels: np.ndarray):
    """A dataset of ``sop_class`` with its file meta, modality and ``pixels`` (uint16; rows x columns, or
    frames x rows x columns)."""
    from pydicom.dataset import Dataset, FileMetaDataset
    from pydicom.uid import ExplicitVRLittleEndian, generate_uid

    meta = FileMetaDataset()
    meta.MediaStorageSOPClassUID, meta.MediaStorageSOPInstanceUID = sop_class, generate_uid()
    meta.TransferSyntaxUID = ExplicitVRLittleEndian
    ds = Dataset()
    ds.file_meta = meta
    ds.SOPClassUID, ds.SOPInstanceUID, ds.Modality = sop_class, meta.MediaStorageSOPInstanceUID, "MR"
    if pixels.ndim == 3:
        ds.NumberOfFrames = pixels.shape[0]
    ds.Rows, ds.Columns = pixels.shape[-2:]
    ds.SamplesPerPixel, ds.PhotometricInterpretation = 1, "MONOCHROME2"
    ds.BitsAllocated, ds.BitsStored, ds.HighBit, ds.PixelRepresentation = 16, 16, 15, 0
    ds.PixelData = np.ascontiguousarray(pixels).astype("<u2").tobytes()
    return ds


def write_series(folder, stored: np.ndarray, spacing_mm, angle_deg: float, order, names=None, number: int = 1,
                 description: str = "T2", at=None, angles=None) -> str:
    """One file per slice; ``stored`` is (columns, rows, slices); files are written in ``order``; returns the
    SeriesInstanceUID (a new series per call, numbered ``number``).

    File k of the write order holds slice order[k] and is named ``names[k]`` (default IM<k>). Slice s lies
    ``at[s]`` slices along the normal (default s) in the plane turned by ``angles[s]`` (default
    ``angle_deg``).
    """
    from pydicom.uid import MRImageStorage, generate_uid

    folder.mkdir(parents=True, exist_ok=True)
    normal = np.cross(*_cosines(angle_deg))
    dc, dr, ds_mm = spacing_mm
    series, frame = generate_uid(), generate_uid()
    for k, s in enumerate(order):
        row, col = _cosines(angle_deg if angles is None else angles[s])
        ds = _image_dataset(MRImageStorage, stored[:, :, s].T)          # rows x columns
        ds.SeriesInstanceUID, ds.FrameOfReferenceUID = series, frame
        ds.SeriesNumber, ds.SeriesDescription, ds.InstanceNumber = number, description, int(s) + 1
        step = s if at is None else at[s]
        ds.ImagePositionPatient = [f"{v:.{DS_DECIMALS - 2}f}" for v in ORIGIN_LPS + step * ds_mm * normal]
        ds.ImageOrientationPatient = [f"{v:.{DS_DECIMALS}f}" for v in (*row, *col)]
        ds.PixelSpacing = [dr, dc]
        ds.SliceThickness = ds_mm
        ds.RescaleSlope, ds.RescaleIntercept = SLOPE, INTERCEPT
        ds.save_as(folder / (names[k] if names else f"IM{k}"), enforce_file_format=True)
    return series


def write_multiframe(path, stored: np.ndarray, spacing_mm, angle_deg: float, order, at=None) -> None:
    """One enhanced MR file (multi-frame): frame k holds slice order[k], placed by its own Plane Position
    functional group (slice s ``at[s]`` slices along the normal; default s); orientation, pixel measures
    and rescale in the shared functional groups."""
    from pydicom.dataset import Dataset
    from pydicom.sequence import Sequence
    from pydicom.uid import EnhancedMRImageStorage, generate_uid

    def item(**values) -> Dataset:
        ds = Dataset()
        for key, value in values.items():
            setattr(ds, key, value)
        return ds

    row, col = _cosines(angle_deg)
    normal, cosines = np.cross(row, col), [f"{v:.{DS_DECIMALS}f}" for v in (*row, *col)]
    dc, dr, ds_mm = spacing_mm
    ds = _image_dataset(EnhancedMRImageStorage, np.stack([stored[:, :, s].T for s in order]))
    ds.SeriesInstanceUID, ds.SeriesNumber = generate_uid(), 1
    ds.SharedFunctionalGroupsSequence = Sequence([item(
        PlaneOrientationSequence=Sequence([item(ImageOrientationPatient=cosines)]),
        PixelMeasuresSequence=Sequence([item(PixelSpacing=[dr, dc], SliceThickness=ds_mm)]),
        PixelValueTransformationSequence=Sequence([item(RescaleSlope=SLOPE, RescaleIntercept=INTERCEPT,
                                                        RescaleType="US")]))])
    ds.PerFrameFunctionalGroupsSequence = Sequence([item(PlanePositionSequence=Sequence([item(
        ImagePositionPatient=[f"{v:.{DS_DECIMALS - 2}f}"
                              for v in ORIGIN_LPS + (s if at is None else at[s]) * ds_mm
                              * normal])]))
        for s in order])
    path.parent.mkdir(parents=True, exist_ok=True)
    ds.save_as(path, enforce_file_format=True)


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
    write_series(tmp_path / "s", stored, spacing, 30.0, order=[3, 0, 4, 1, 2],
                 names=["b", "e", "a", "d", "c"])
    (tmp_path / "s" / "notes.txt").write_text("not DICOM")
    scan = load_scan(str(tmp_path / "s"))
    assert scan.kind == "dicom" and scan.data.shape == (7, 6, 5)
    np.testing.assert_allclose(scan.data, recovered, atol=1e-4)
    np.testing.assert_allclose(scan.affine, expected_affine(spacing, 30.0), atol=1e-5)
    np.testing.assert_allclose(scan.spacing_mm, spacing, atol=1e-5)
    write_multiframe(tmp_path / "m" / "enhanced.dcm", stored, spacing, 30.0, order=[3, 0, 4, 1, 2])
    frames = load_scan(str(tmp_path / "m"))
    np.testing.assert_allclose(frames.data, recovered, atol=1e-4)
    np.testing.assert_allclose(frames.affine, scan.affine, atol=1e-5)


def test_dicom_in_any_file_order_labels_like_the_nifti(run_less, tmp_path, scan_volume):
    image, spacing = scan_volume
    stored, recovered = quantised(image)
    n = stored.shape[2]
    write_series(tmp_path / "ordered", stored, spacing, -25.0, order=list(range(n)))
    shuffled = np.random.default_rng(1).permutation(n)
    write_series(tmp_path / "shuffled", stored, spacing, -25.0, order=shuffled,
                 names=[f"{int(v):03d}.dcm" for v in np.random.default_rng(2).permutation(n)])
    write_multiframe(tmp_path / "enhanced" / "IM0", stored, spacing, -25.0, order=shuffled)
    write_series(tmp_path / "export" / "SE1", stored, spacing, -25.0, order=list(range(n)))
    write_series(tmp_path / "export" / "SE2", stored[:, :, :3], (1.0, 1.0, 5.0), 0.0, order=range(3),
                 number=2, description="localizer")
    nifti = nib.Nifti1Image(recovered.astype(np.float32), expected_affine(spacing, -25.0))
    nib.save(nifti, tmp_path / "scan.nii.gz")
    labels = {}
    for source, options in (("scan.nii.gz", ()), ("ordered", ()), ("shuffled", ()), ("enhanced", ()),
                            ("export", ("--series", "1"))):
        out = f"{source.split('.')[0]}_labels.nii.gz"
        run_less("mri-label", source, *options, "-o", out, check=True)
        img = nib.load(tmp_path / out)
        labels[source] = (np.asarray(img.dataobj), img.affine)
    ref, ref_affine = labels["scan.nii.gz"]
    assert set(np.unique(ref)) == {0, 1, 2, 3}
    for source in ("ordered", "shuffled", "enhanced", "export"):
        np.testing.assert_array_equal(labels[source][0], ref)
        np.testing.assert_allclose(labels[source][1], ref_affine, atol=1e-5)


def _series_values(shape=(7, 6, 5), seed=0):
    return quantised(np.random.default_rng(seed).uniform(-1.0, 25.0, shape))


@pytest.mark.parametrize("nested", [False, True])
def test_a_folder_of_several_series_reads_the_one_chosen(tmp_path, nested):
    """A scanner's export holds a localizer beside the scan, all in one folder or in patient / study /
    series folders under it: without --series it is one clear error listing both; by SeriesNumber or
    SeriesInstanceUID the chosen one is read, the other left out."""
    from lesscli.errors import DataError
    from lesscli.mri.scan import load_scan

    def folder(*parts):
        return tmp_path.joinpath("s", *parts) if nested else tmp_path / "s"

    stored, recovered = _series_values()
    spacing = (0.6, 0.5, 1.2)
    uid = write_series(folder("P1", "ST1", "SE3"), stored, spacing, 30.0, order=range(5),
                       names=[f"a{k}" for k in range(5)], number=3, description="T2 SPACE")
    write_series(folder("P1", "ST1", "SE1"), _series_values((7, 6, 3), seed=1)[0], (1.0, 1.0, 5.0), 0.0,
                 order=range(3), names=[f"b{k}" for k in range(3)], number=1, description="localizer")
    with pytest.raises(DataError,
                       match=r": 2 series in this folder \(1 'localizer': 3 images; 3 'T2 SPACE': 5 "
                                        r"images\); choose one with --series"):
        load_scan(str(tmp_path / "s"))
    for chosen in ("3", uid):
        scan = load_scan(str(tmp_path / "s"), series=chosen)
        np.testing.assert_allclose(scan.data, recovered, atol=1e-4)
        np.testing.assert_allclose(scan.affine, expected_affine(spacing, 30.0), atol=1e-5)
    with pytest.raises(DataError, match=r"no series '7' in this folder \(its series: 1, 3\)"):
        load_scan(str(tmp_path / "s"), series="7")
    again = write_series(folder("P1", "ST2", "SE3"), stored, spacing, 30.0, order=range(5),
                         # a second exam's
                         names=[f"c{k}" for k in range(5)], number=3, description="T2 SPACE")
    with pytest.raises(DataError,
                       match=r"2 series numbered '3' in this folder; give the SeriesInstanceUID of one"):
        load_scan(str(tmp_path / "s"), series="3")
    np.testing.assert_allclose(load_scan(str(tmp_path / "s"), series=again).data, recovered, atol=1e-4)


@pytest.mark.parametrize("fault, message", [
    ("missing", r"not evenly spaced \(2\.400 mm between IM2 and IM3, 1\.200 mm elsewhere\): a slice missing"),
    ("repeated", r"IM2 and IM3 lie at the same slice position .*several images per position"),
    ("turned", r"IM0 and IM3 have different orientations"),
    ("missing frame",
     r"not evenly spaced \(2\.400 mm between x\.dcm frame 4 and x\.dcm frame 1, 1\.200 mm elsewhere"),
])
def test_a_series_that_is_not_one_volume_is_refused_naming_its_files(run_less, tmp_path, fault, message):
    """A slice missing, two images at one position (echoes) or a slice in another plane: one line naming the
    files (and frames), exit 1, no output (``less mri-label``)."""
    stored, _ = _series_values((7, 6, 4))
    at = {"missing": [0, 1, 2, 4], "repeated": [0, 1, 2, 2], "missing frame": [0, 1, 2, 4]}.get(fault)
    angles = [30.0, 30.0, 30.0, 40.0] if fault == "turned" else None
    if fault == "missing frame":      # frames 1-4 hold slices 3, 0, 1, 2: the gap lies between frames 4 and 1
        write_multiframe(tmp_path / "s" / "x.dcm", stored, (0.6, 0.5, 1.2), 30.0, order=[3, 0, 1, 2], at=at)
    else:
        write_series(tmp_path / "s", stored, (0.6, 0.5, 1.2), 30.0, order=range(4), at=at, angles=angles)
    proc = run_less("mri-label", "s", "-o", "labels.nii.gz")
    err = proc.stderr.decode().strip()
    assert proc.returncode == 1 and len(err.splitlines()) == 1 and err.startswith("less: error: s: "), err
    assert re.search(message, err), err
    assert not (tmp_path / "labels.nii.gz").exists()


def test_series_is_refused_for_a_file(run_less, tmp_path):
    nib.save(nib.Nifti1Image(np.zeros((4, 4, 4), np.float32), np.eye(4)), tmp_path / "scan.nii.gz")
    proc = run_less("mri-label", "scan.nii.gz", "--series", "3", "-o", "labels.nii.gz")
    assert proc.returncode == 1
    assert "scan.nii.gz: --series is for a DICOM folder" in proc.stderr.decode()
    assert not (tmp_path / "labels.nii.gz").exists()


def test_undecodable_pixel_data_is_one_line_naming_the_file(run_less, tmp_path):
    """A compressed transfer syntax whose bytes do not decode: the file named, exit 1."""
    from pydicom import dcmread
    from pydicom.encaps import encapsulate
    from pydicom.uid import JPEGBaseline8Bit

    stored, _ = _series_values((7, 6, 3))
    write_series(tmp_path / "s", stored, (0.6, 0.5, 1.2), 30.0, order=range(3))
    ds = dcmread(tmp_path / "s" / "IM1")
    ds.file_meta.TransferSyntaxUID = JPEGBaseline8Bit
    ds.PixelData = encapsulate([b"\xff\xd8 not a JPEG" + b"\x00" * 64])
    ds.save_as(tmp_path / "s" / "IM1", enforce_file_format=True)
    proc = run_less("mri-label", "s", "-o", "labels.nii.gz")
    err = proc.stderr.decode().strip()
    assert proc.returncode == 1 and len(err.splitlines()) == 1, err
    assert "IM1: pixel data not decodable" in err
    assert not (tmp_path / "labels.nii.gz").exists()


def test_info_describes_a_dicom_series_and_a_nifti_scan(run_less, tmp_path, scan_volume):
    """``less info`` on an MRI scan: the grid and intensities of a DICOM folder (one series chosen where it
    holds several) and of the same scan as NIfTI; label codes alone make a label volume instead."""
    import json

    image, spacing = scan_volume
    stored, recovered = quantised(image)
    write_series(tmp_path / "export" / "SE1", stored, spacing, -25.0, order=range(stored.shape[2]))
    write_series(tmp_path / "export" / "SE2", stored[:, :, :3], (1.0, 1.0, 5.0), 0.0, order=range(3),
                 number=2)
    nib.save(nib.Nifti1Image(recovered.astype(np.float32), expected_affine(spacing, -25.0)),
             tmp_path / "scan.nii.gz")
    records = {}
    for source, options in (("export", ("--series", "1")), ("scan.nii.gz", ())):
        proc = run_less("info", source, *options, "--format", "jsonl", check=True)
        records[source] = json.loads(proc.stdout)
    for record in records.values():      # the grid z, y, x, as a label volume's; the file's axes run x, y, z
        assert record["kind"] == "image volume" and record["shape"] == list(stored.shape[::-1])
        assert (record["axes"], record["file_axes"]) == ("z, y, x", "x, y, z")
        np.testing.assert_allclose(record["spacing_mm"], spacing[::-1], atol=1e-5)
        assert record["intensity"]["min"] == pytest.approx(recovered.min(), abs=1e-3)
        assert record["intensity"]["max"] == pytest.approx(recovered.max(), abs=1e-3)
        assert record["intensity"]["median"] == pytest.approx(np.median(recovered), abs=1e-3)
    assert (records["export"]["format"], records["scan.nii.gz"]["format"]) == ("dicom", "nifti")
    several = run_less("info", "export")
    assert several.returncode == 1 and b"2 series in this folder" in several.stderr and not several.stdout
    on_a_file = run_less("info", "scan.nii.gz", "--series", "1")
    assert on_a_file.returncode == 1 and b"--series is for a DICOM folder" in on_a_file.stderr
    codes = nib.Nifti1Image((recovered > np.median(recovered)).astype(np.uint8), np.diag([*spacing, 1.0]))
    nib.save(codes, tmp_path / "codes.nii.gz")
    labels = json.loads(run_less("info", "codes.nii.gz", "--format", "jsonl", check=True).stdout)
    assert labels["kind"] == "label volume" and sum(labels["class_voxels"].values()) == stored.size
