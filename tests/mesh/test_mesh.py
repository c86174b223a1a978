"""Meshes: physical volume, outward orientation, one node per class, CLI formats and errors."""

import math

import numpy as np
import pytest
import trimesh
from factories import sphere_labels

from lesscli.io.labels import save_nifti
from lesscli.io.predictions import PredictionSet, ScanPrediction, save_predictions
from lesscli.mesh.surfaces import label_meshes

RADIUS_MM = 6.0


@pytest.fixture(scope="module")
def sphere():
    return sphere_labels(center_mm=(-11.0, 2.0, -3.0), radius_mm=RADIUS_MM)


def test_sphere_volume_and_orientation(sphere):
    (inc,) = label_meshes(sphere, codes=(3,))
    true = 4.0 / 3.0 * math.pi * RADIUS_MM**3
    assert inc.mesh.is_watertight
    assert inc.mesh.volume > 0
    assert abs(inc.mesh.volume - true) / true < 0.05
    # outward normals: every face normal points away from the centre
    centre = np.array([-3.0, 2.0, -11.0])                       # x, y, z
    radial = inc.mesh.triangles_center - centre
    assert (np.einsum("ij,ij->i", radial, inc.mesh.face_normals) > 0).mean() > 0.99
    assert np.allclose(inc.mesh.centroid, centre, atol=0.1)


def test_decimation_keeps_volume(sphere):
    (inc,) = label_meshes(sphere, codes=(3,), target_faces=400)
    true = 4.0 / 3.0 * math.pi * RADIUS_MM**3
    assert len(inc.mesh.faces) <= 420 and inc.mesh.volume > 0
    assert abs(inc.mesh.volume - true) / true < 0.05


def test_cli_glb_from_nifti_has_a_node_per_class(tmp_path, run_less, sphere):
    save_nifti(str(tmp_path / "s.nii.gz"), sphere)
    proc = run_less("mesh", "s.nii.gz", "-o", "s.glb", "--format", "jsonl", "--smooth", "4")
    assert proc.returncode == 0, proc.stderr.decode()
    rows = [__import__("json").loads(line) for line in proc.stdout.decode().splitlines()]
    assert [r["class"] for r in rows] == ["insert", "inclusion"]
    scene = trimesh.load(str(tmp_path / "s.glb"))
    assert sorted(scene.graph.nodes_geometry) == ["inclusion", "insert"]
    inc = scene.geometry["inclusion"]
    # glTF means metres with +Y up: the 12 mm sphere is 0.012 m across, its centre (x, y, z) = (-3, 2, -11) mm
    # at (x, z, -y) = (-0.003, -0.011, -0.002) m, and its normals still point outward (positive volume)
    assert inc.volume == pytest.approx(rows[1]["volume_mm3"] * 1e-9, rel=1e-4) and inc.volume > 0
    assert inc.extents == pytest.approx([2 * RADIUS_MM * 1e-3] * 3, rel=0.1)
    assert inc.centroid == pytest.approx([-0.003, -0.011, -0.002], abs=1e-4)
    stl = run_less("mesh", "s.nii.gz", "-o", "s.stl", "--classes", "inclusion", "--smooth", "4")
    assert (stl.returncode == 0
            and trimesh.load(str(tmp_path / "s.stl")).extents == pytest.approx([12.0] * 3, rel=0.1))


@pytest.mark.parametrize("ext", ["stl", "ply"])
def test_cli_prediction_truth_to_single_mesh(tmp_path, run_less, sphere, ext):
    probs = np.zeros((4, *sphere.shape), np.float32)
    probs[1] = 1.0
    save_predictions(str(tmp_path / "p.npz"), PredictionSet(
        [ScanPrediction(probs, sphere.origin_mm, sphere.spacing_mm, truth=sphere.data)], {"dim": 3}))
    proc = run_less("mesh", "p.npz", "--truth", "--classes", "inclusion", "-o", f"inc.{ext}")
    assert proc.returncode == 0, proc.stderr.decode()
    mesh = trimesh.load(str(tmp_path / f"inc.{ext}"))
    assert abs(mesh.volume - 4.0 / 3.0 * math.pi * RADIUS_MM**3) < 0.05 * 905
    # the predicted labels hold no inclusion: a clear error and no output file
    proc = run_less("mesh", "p.npz", "--classes", "inclusion", "-o", "none.glb")
    assert proc.returncode == 1 and b"nothing to mesh" in proc.stderr
    assert not (tmp_path / "none.glb").exists()


def test_cli_errors(tmp_path, run_less):
    proc = run_less("mesh", "missing.nii.gz", "-o", "x.glb")
    assert proc.returncode == 1 and b"missing.nii.gz" in proc.stderr
    proc = run_less("mesh", "missing.nii.gz", "-o", "x.obj")
    assert proc.returncode == 1 and b"x.obj" in proc.stderr
    proc = run_less("mesh", "missing.nii.gz", "-o", "x.glb", "--classes", "inclusio")
    assert proc.returncode == 2 and b"did you mean 'inclusion'" in proc.stderr
