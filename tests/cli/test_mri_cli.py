"""`less mri-label`: synthesise -> label -> metrics, phantom grid with 8 orientations, bad inputs."""

from __future__ import annotations

import json

import nibabel as nib
import numpy as np
import pytest

from lesscli.io.labels import INCLUSION, load_nifti_labels
from lesscli.metrics import dice
from lesscli.mri.synth import MRIParams, synthesize
from lesscli.phantom.catalogue import single_insert
from lesscli.phantom.geometry import Phantom, label_grid_origin

SYNTH_SPACING = "0.7,0.7,0.7"


@pytest.fixture(scope="module")
def synth_files(tmp_path_factory):
    """A synthetic scan of St12C13 with its truth, written by the CLI once for the module."""
    import subprocess
    import sys
    from pathlib import Path

    folder = tmp_path_factory.mktemp("mri")
    less = Path(sys.executable).parent / "less"
    subprocess.run([str(less), "mri-label", "--synth", "St12C13", "-o", "scan.nii.gz", "--truth-out",
                    "truth.nii.gz", "--spacing-mm", SYNTH_SPACING, "--seed", "3", "--contrast",
                    "silicone-brighter"],
                   cwd=folder, check=True, capture_output=True)
    return folder


def _one_line_error(proc) -> str:
    err = proc.stderr.decode()
    assert proc.returncode == 1, err
    assert "Traceback" not in err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    return lines[0]


def test_synth_label_metrics_roundtrip(run_less, synth_files, tmp_path):
    scan, truth = synth_files / "scan.nii.gz", synth_files / "truth.nii.gz"
    proc = run_less("mri-label", scan, "-o", "labels.nii.gz", "--report", "--format", "jsonl", "--plot",
                    "qc.png", check=True)
    rows = [json.loads(line) for line in proc.stdout.decode().splitlines()]
    contrast = next(r for r in rows if r["row"] == "contrast")
    assert contrast["silicone_brighter"] is True and contrast["silicone"] > contrast["hydrogel"]
    inclusions = [r for r in rows if r["row"] == "inclusion"]
    assert len(inclusions) == 1 and abs(inclusions[0]["diameter_mm"] - 12.0) < 1.0
    shape = [r for r in rows if r["row"] == "inclusion_shape"]
    assert len(shape) == 1 and shape[0]["shape"] in ("ball", "image")
    assert abs(shape[0]["ball_diameter_mm"] - 12.0) < 1.0 and 0.0 < shape[0]["ball_misfit"] < 10.0
    assert np.linalg.norm(np.subtract(shape[0]["centre_mm"], inclusions[0]["centroid_mm"])) < 1.0
    assert not [r for r in rows if r["row"] == "warning"]
    (base,) = [r for r in rows if r["row"] == "base_surface"]
    assert (tmp_path / "qc.png").stat().st_size > 1000
    out, ref = nib.load(tmp_path / "labels.nii.gz"), nib.load(scan)
    np.testing.assert_allclose(out.affine, ref.affine)
    assert out.shape == ref.shape
    pred, true = load_nifti_labels(str(tmp_path / "labels.nii.gz")), load_nifti_labels(str(truth))
    assert dice(pred.data == INCLUSION, true.data == INCLUSION) > 0.93
    # the base surface in the scan's world frame: square to the insert's axis (its least spread), and the
    # true pillar ends on it, on the filling's side
    from lesscli.io.labels import PILLAR
    from lesscli.mri.frame import voxel_to_world

    normal, truth_img = np.asarray(base["normal"]), nib.load(truth)
    codes = np.asarray(truth_img.dataobj)                   # the NIfTI's own axes, as its affine maps them
    whole = voxel_to_world(np.argwhere(codes > 0), truth_img.affine)
    axis = np.linalg.svd(whole - whole.mean(axis=0), full_matrices=False)[2][2]
    assert abs(np.linalg.norm(normal) - 1.0) < 1e-4 and abs(axis @ normal) > 0.99
    height = (voxel_to_world(np.argwhere(codes == PILLAR), truth_img.affine) - base["point_mm"]) @ normal
    assert -1.0 < height.max() < 0.0                    # the post's last voxel centres within a voxel of it
    # the post drawn: up the insert's axis from its foot on that surface, on the true post's axis, as wide
    from lesscli.phantom.catalogue import PILLAR_RADIUS_MM

    (post,) = [r for r in rows if r["row"] == "pillar"]
    up, foot = np.asarray(post["direction"]), np.asarray(post["foot_mm"])
    assert abs(up @ axis) > 0.99 and up @ normal < 0.0
    assert abs((foot - base["point_mm"]) @ normal) < 0.01
    true_post = voxel_to_world(np.argwhere(codes == PILLAR), truth_img.affine).mean(axis=0)
    lateral = (true_post - foot) - ((true_post - foot) @ up) * up
    assert np.linalg.norm(lateral) < 0.5 * 0.7
    assert abs(post["diameter_mm"] - 2 * PILLAR_RADIUS_MM) < 0.25 * 0.7 and post["height_mm"] > 0.0
    metrics = run_less("metrics", "--truth", truth, "--pred", "labels.nii.gz", "--format", "jsonl",
                       check=True)
    first = json.loads(metrics.stdout.decode().splitlines()[0])
    assert first["f1_3d"] > 0.93


def test_phantom_grid_writes_eight_orientations(run_less, synth_files, tmp_path):
    run_less("mri-label", synth_files / "scan.nii.gz", "-o", "grid.nii.gz", "--grid", "phantom",
             "--orientations", "0-7", check=True)
    vols = [load_nifti_labels(str(tmp_path / f"grid_{k}.nii.gz")) for k in range(8)]
    assert not (tmp_path / "grid.nii.gz").exists()
    for vol in vols:
        assert vol.shape == (26, 128, 128)
        np.testing.assert_allclose(vol.origin_mm, label_grid_origin((26, 128, 128), (0.9, 0.4774, 0.4774)),
                                   atol=1e-4)
        assert (vol.data == INCLUSION).sum() > 100
    # a 90 degree step maps the centred square grid onto itself: orientation 2 is orientation 0 turned x -> y
    turned = np.rot90(vols[0].data, k=1, axes=(2, 1))
    assert dice(turned == INCLUSION, vols[2].data == INCLUSION) > 0.98
    assert dice(vols[0].data == INCLUSION, vols[1].data == INCLUSION) < 0.5


def test_numpy_scan_with_spacing(run_less, tmp_path):
    params = MRIParams(spacing_mm=(0.9, 0.6, 0.6), noise_sigma=0.03, supersample=1)
    synth = synthesize(single_insert(14, "D", 9), np.random.default_rng(5), params)
    np.save(tmp_path / "scan.npy", synth.image)
    run_less("mri-label", "scan.npy", "--spacing-mm", "0.9,0.6,0.6", "-o", "labels.nii.gz", check=True)
    labels = load_nifti_labels(str(tmp_path / "labels.nii.gz"))
    np.testing.assert_allclose(labels.spacing_mm, [0.9, 0.6, 0.6])
    assert labels.shape == synth.labels.shape
    assert dice(labels.data == INCLUSION, synth.labels.data == INCLUSION) > 0.93
    assert dice(labels.data > 0, synth.labels.data > 0) > 0.97


def test_inclusion_shape_option(run_less, synth_files, tmp_path):
    """--inclusion-shape image / ball choose the inclusion's surface; both overlap the truth's inclusion."""
    truth = load_nifti_labels(str(synth_files / "truth.nii.gz")).data == INCLUSION
    out = {}
    for shape in ("image", "ball"):
        run_less("mri-label", synth_files / "scan.nii.gz", "-o", f"{shape}.nii.gz", "--inclusion-shape",
                 shape, check=True)
        out[shape] = load_nifti_labels(str(tmp_path / f"{shape}.nii.gz")).data == INCLUSION
        assert dice(out[shape], truth) > 0.93
    assert (out["image"] != out["ball"]).any()
    proc = run_less("mri-label", synth_files / "scan.nii.gz", "-o", "x.nii.gz", "--inclusion-shape", "cube")
    assert proc.returncode == 2 and not (tmp_path / "x.nii.gz").exists()


def _bad_arrays(tmp_path) -> dict:
    rng = np.random.default_rng(0)
    noise = np.abs(rng.normal(0, 1, (48, 48, 48)) + 1j * rng.normal(0, 1, (48, 48, 48)))
    with_nan = rng.random((32, 32, 32))
    with_nan[5, 6, 7] = np.nan
    arrays = {"flat.npy": rng.random((64, 64)), "nan.npy": with_nan, "empty.npy": np.zeros((32, 32, 32)),
              "noise.npy": noise}
    for name, arr in arrays.items():
        np.save(tmp_path / name, arr)
    return arrays


@pytest.mark.parametrize("name, spacing, message", [
    ("flat.npy", "1,1,1", "expected a 3D volume"),
    ("nan.npy", "1,1,1", "NaN"),
    ("empty.npy", "1,1,1", "volume is empty"),
    ("noise.npy", "1,1,1", "no insert found"),
    ("noise.npy", None, "needs --spacing-mm"),
    ("missing.nii.gz", None, "no such file"),
    ("scan.txt", None, "unknown scan format"),
])
def test_bad_inputs_fail_with_one_line(run_less, tmp_path, name, spacing, message):
    _bad_arrays(tmp_path)
    (tmp_path / "scan.txt").write_text("not a scan")
    args = ["mri-label", name, "-o", "out.nii.gz"] + (["--spacing-mm", spacing] if spacing else [])
    line = _one_line_error(run_less(*args))
    assert name in line and message in line
    assert not (tmp_path / "out.nii.gz").exists()


def test_no_inclusion_warns_and_strict_fails(run_less, tmp_path):
    empty_insert = Phantom("Plain")
    params = MRIParams(spacing_mm=(1.0, 1.0, 1.0), supersample=1, noise_sigma=0.03)
    np.save(tmp_path / "plain.npy", synthesize(empty_insert, np.random.default_rng(1), params).image)
    proc = run_less("mri-label", "plain.npy", "--spacing-mm", "1,1,1", "-o", "out.nii.gz")
    assert proc.returncode == 0 and "no inclusion found" in proc.stderr.decode()
    assert (tmp_path / "out.nii.gz").exists()
    line = _one_line_error(run_less("mri-label", "plain.npy", "--spacing-mm", "1,1,1", "-o", "strict.nii.gz",
                                    "--strict"))
    assert "no inclusion found" in line and not (tmp_path / "strict.nii.gz").exists()


def test_dicom_folder_without_images_is_a_clear_error(run_less, tmp_path):
    (tmp_path / "series").mkdir()
    line = _one_line_error(run_less("mri-label", "series", "-o", "out.nii.gz"))
    assert "no DICOM images" in line


def test_a_toolkit_file_is_told_not_an_mri_scan(run_less, tmp_path):
    from factories import random_scanset

    from lesscli.io.scans import save_scans

    save_scans(str(tmp_path / "scans.npz"), random_scanset())
    for spacing in ((), ("--spacing-mm", "1,1,1")):
        line = _one_line_error(run_less("mri-label", "scans.npz", *spacing, "-o", "out.nii.gz"))
        assert "scans.npz: a less.scans file, not an MRI scan" in line
    assert not (tmp_path / "out.nii.gz").exists()


def test_usage_errors(run_less, synth_files, tmp_path):
    proc = run_less("mri-label", synth_files / "scan.nii.gz", "-o", "x.nii.gz", "--spacing-mm", "1,0,1")
    assert proc.returncode == 2 and "three positive numbers" in proc.stderr.decode()
    proc = run_less("mri-label", synth_files / "scan.nii.gz", "-o", "x.nii.gz", "--orientations", "0-7")
    assert proc.returncode == 2 and "--grid phantom" in proc.stderr.decode()
    line = _one_line_error(run_less("mri-label", "--synth", "St12C31", "-o", "x.nii.gz"))
    assert "did you mean" in line
    proc = run_less("mri-label", synth_files / "scan.nii.gz", "-o", "x.nii.gz", "--pillar-diameter-mm", "5")
    assert proc.returncode == 2 and "thickest pillar's (4.5 mm)" in proc.stderr.decode()
    assert not (tmp_path / "x.nii.gz").exists()
    proc = run_less("mri-label", synth_files / "scan.nii.gz", "-o", "x.nii.gz", "--bias-degree", "7")
    assert proc.returncode == 2 and "--bias-degree" in proc.stderr.decode()


def test_bias_degree_option_reaches_the_correction(run_less, synth_files, tmp_path):
    """`--bias-degree 0` labels without the bias correction: other labels than the default's, still the
    inclusion (the scan's bias is 0.25)."""
    truth = load_nifti_labels(str(synth_files / "truth.nii.gz")).data
    out = {}
    for degree in ("0", "3"):
        run_less("mri-label", synth_files / "scan.nii.gz", "-o", f"d{degree}.nii.gz", "--bias-degree", degree,
                 check=True)
        out[degree] = load_nifti_labels(str(tmp_path / f"d{degree}.nii.gz")).data
    assert (out["0"] != out["3"]).any()
    assert dice(out["0"] == INCLUSION, truth == INCLUSION) > 0.9


def test_given_pillar_diameter_is_drawn_and_the_measured_one_reported(run_less, synth_files, tmp_path):
    """`--pillar-diameter-mm`: the post drawn that wide, where the scan places it, its measured diameter in
    the report; the inclusion as without it (within the voxels its surface is fitted clear of the post)."""
    from lesscli.io.labels import PILLAR
    from lesscli.phantom.catalogue import PILLAR_RADIUS_MM

    rows = {}
    for name, extra in (("blind", ()), ("given", ("--pillar-diameter-mm", "4.4"))):
        proc = run_less("mri-label", synth_files / "scan.nii.gz", "-o", f"{name}.nii.gz", "--report",
                        "--format", "jsonl", *extra, check=True)
        (rows[name],) = [r for r in map(json.loads, proc.stdout.decode().splitlines())
                         if r["row"] == "pillar"]
    assert rows["given"]["diameter_mm"] == 4.4 and "measured_diameter_mm" not in rows["blind"]
    assert rows["given"]["measured_diameter_mm"] == rows["blind"]["diameter_mm"]
    assert abs(rows["blind"]["diameter_mm"] - 2 * PILLAR_RADIUS_MM) < 0.25 * 0.7
    assert rows["given"]["foot_mm"] == rows["blind"]["foot_mm"]
    blind, given = (load_nifti_labels(str(tmp_path / f"{name}.nii.gz")).data for name in ("blind", "given"))
    assert (given == PILLAR).sum() > (blind == PILLAR).sum()
    assert dice(given == INCLUSION, blind == INCLUSION) > 0.98      # the ball is fitted clear of the post


def test_phantom_command_writes_synthetic_mri(run_less, tmp_path):
    proc = run_less("phantom", "--set", "single", "--names", "St8C5", "--orientations", "0", "--mri", "-o",
                    "ph", "--format", "jsonl", check=True)
    rows = [json.loads(line) for line in proc.stdout.decode().splitlines()]
    mri_rows = [r for r in rows if "mri" in r]
    assert len(mri_rows) == 1 and mri_rows[0]["insert"] == "St8C5"
    truth = load_nifti_labels(str(tmp_path / "ph" / "mri" / "St8C5_0_truth.nii.gz"))
    image = nib.load(tmp_path / "ph" / "mri" / "St8C5_0.nii.gz")
    assert image.shape == truth.shape[::-1] and (truth.data == INCLUSION).sum() > 0
    proc = run_less("phantom", "--stl", "x.stl", "--mri", "-o", "cad")
    assert proc.returncode == 2 and "--mri needs --set" in proc.stderr.decode()
