"""Phantom catalogues, phantom-set files, STL voxelisation and the ``less phantom`` command."""

import json
import math

import numpy as np
import pytest

from lesscli.errors import DataError
from lesscli.io.labels import INCLUSION, INSERT, PILLAR, load_nifti_labels
from lesscli.phantom.catalogue import CATALOGUES, FAMILY_ANGLE_DEG, load_phantom_file, resolve_set
from lesscli.phantom.geometry import Phantom, Sphere


def test_single_names_encode_diameter_family_and_offset():
    phantoms = CATALOGUES["single"]()
    assert len(phantoms) == len({p.name for p in phantoms}) >= 24
    for p in phantoms:
        (s,) = p.inclusions
        diameter, family, offset = p.name[2:].partition("C" if "C" in p.name else "D")
        assert 2 * s.radius_mm == pytest.approx(float(diameter))
        assert math.hypot(*s.center_mm[:2]) == pytest.approx(float(offset))
        assert (math.degrees(math.atan2(s.center_mm[1], s.center_mm[0]))
                == pytest.approx(FAMILY_ANGLE_DEG[family]))
        assert 8 <= 2 * s.radius_mm <= 16 and 5 <= float(offset) <= 15
        assert s.center_mm[2] + s.radius_mm < -p.skin_thickness_mm        # under the skin
        assert len(p.pillars) == 1 and p.pillars[0].z_top_mm == s.center_mm[2]
    assert "St12C13" in {p.name for p in phantoms}


def _inside_octagon(p: Phantom, s: Sphere) -> bool:
    ang = np.linspace(0, 2 * np.pi, 64)
    return bool(p.inside_outline(s.center_mm[0] + s.radius_mm * np.cos(ang),
                                 s.center_mm[1] + s.radius_mm * np.sin(ang)).all())


def test_multiple_has_chains_curves_and_separate_inclusions_inside_the_insert():
    phantoms = CATALOGUES["multiple"]()
    counts = [len(p.inclusions) for p in phantoms]
    assert min(counts) >= 2 and max(counts) >= 3
    connected = 0
    for p in phantoms:
        assert all(_inside_octagon(p, s) for s in p.inclusions)
        gaps = [math.dist(a.center_mm, b.center_mm) - a.radius_mm - b.radius_mm
                for a, b in zip(p.inclusions, p.inclusions[1:])]
        if p.name.startswith(("Ch", "Cv")):
            assert max(gaps) < 0, p.name                      # neighbours overlap: one connected body
            connected += 1
        else:
            assert min(gaps) > 0, p.name
    assert connected >= 4


def test_large_is_twice_as_wide_with_usual_inclusions():
    phantoms = CATALOGUES["large"]()
    assert all(p.width_mm == 120.0 and p.height_mm == 30.0 for p in phantoms)
    assert all(p.name.startswith("bst") for p in phantoms) and "bst12d30" in {p.name for p in phantoms}
    assert all(8 <= 2 * p.inclusions[0].radius_mm <= 16 for p in phantoms)


def test_phantom_files_toml_and_json(tmp_path):
    base = CATALOGUES["single"]()[3]
    toml = tmp_path / "set.toml"
    toml.write_text('[[phantom]]\nname = "homog"\n\n[[phantom]]\nname = "one"\n'
                    'inclusions = [{center_mm = [5.0, 0.0, -10.0], radius_mm = 4.0}]\n')
    got = load_phantom_file(str(toml))
    assert [p.name for p in got] == ["homog", "one"] and got[1].inclusions[0].radius_mm == 4.0
    spec = tmp_path / "spec.json"
    spec.write_text(json.dumps(base.rotated(2).to_dict()))
    assert load_phantom_file(str(spec)) == [base.rotated(2)]
    bad = tmp_path / "bad.toml"
    bad.write_text('[[phantom]]\nname = "x"\nheigth_mm = 3\n')
    with pytest.raises(DataError,
                       match=r"bad.toml: phantom 0: unknown key 'heigth_mm'; did you mean 'height_mm'"):
        load_phantom_file(str(bad))
    with pytest.raises(DataError, match="did you mean 'multiple'"):
        resolve_set("multiple2")


def _box_stl(path, extents, center=(0, 0, 0)):
    import trimesh

    trimesh.creation.box(extents=extents).apply_translation(center).export(path)


def _ball_stl(path, radius, center):
    import trimesh

    trimesh.creation.icosphere(subdivisions=4, radius=radius).apply_translation(center).export(path)


def test_stl_voxelisation_matches_analytic_geometry(tmp_path):
    from lesscli.phantom.stl import stl_label_volume

    _box_stl(tmp_path / "insert.stl", (40, 40, 20), center=(100, 50, 10))      # CAD frame: base at z = 0
    _ball_stl(tmp_path / "ball.stl", 5.0, (108, 50, 12))                       # 8 mm off-centre, 8 mm deep
    vol, spec = stl_label_volume(str(tmp_path / "insert.stl"), [str(tmp_path / "ball.stl")],
                                 shape=(20, 64, 64), spacing_mm=(1.0, 1.0, 1.0))
    assert spec["shift_mm"] == [-100.0, -50.0, -20.0]
    z, y, x = np.meshgrid(*vol.axes_mm(), indexing="ij")
    box = (np.abs(x) <= 20) & (np.abs(y) <= 20) & (z >= -20)
    ball = (x - 8) ** 2 + y**2 + (z + 8) ** 2 <= 25
    expect = np.where(ball, INCLUSION, np.where(box, INSERT, 0))
    near_ball = np.abs(np.sqrt((x - 8) ** 2 + y**2 + (z + 8) ** 2) - 5) < 0.1   # faceted sphere vs exact
    assert (vol.data[~near_ball] == expect[~near_ball]).all()
    # a quarter turn moves the inclusion from +x to +y
    rot, _ = stl_label_volume(str(tmp_path / "insert.stl"), [str(tmp_path / "ball.stl")], orientation=2,
                              shape=(20, 64, 64), spacing_mm=(1.0, 1.0, 1.0))
    zi, yi, xi = np.nonzero(rot.data == INCLUSION)
    assert (np.mean(x[zi, yi, xi]) == pytest.approx(0, abs=0.2)
            and np.mean(y[zi, yi, xi]) == pytest.approx(8, abs=0.2))


def test_stl_not_watertight_is_a_clear_error(tmp_path):
    import trimesh

    from lesscli.phantom.stl import load_mesh

    mesh = trimesh.creation.box(extents=(10, 10, 10))
    mesh.update_faces(np.arange(len(mesh.faces)) > 0)
    mesh.export(tmp_path / "open.stl")
    with pytest.raises(DataError, match="open.stl: mesh is not watertight"):
        load_mesh(str(tmp_path / "open.stl"))


def test_cli_phantom_set_writes_labels_and_specs(run_less, tmp_path):
    proc = run_less("phantom", "--set", "single", "--names", "St12C13", "--orientations", "0,2",
                    "--grid-shape", "8,32,32", "--spacing-mm", "2,2,2", "-o", "out", check=True)
    rows = [json.loads(line) for line in proc.stdout.decode().splitlines()]
    assert [(r["insert"], r["orientation"]) for r in rows] == [("St12C13", 0), ("St12C13", 2)]
    assert all(r["inclusion_voxels"] > 0 for r in rows)
    vol = load_nifti_labels(str(tmp_path / "out" / "St12C13_2.nii.gz"))
    assert vol.shape == (8, 32, 32) and set(np.unique(vol.data)) <= {0, INSERT, PILLAR, INCLUSION}
    expect = Phantom.from_dict(json.loads((tmp_path / "out" / "St12C13_2.json").read_text()))
    np.testing.assert_array_equal(vol.data, expect.label_volume((8, 32, 32), (2, 2, 2)).data)
    assert load_phantom_file(str(tmp_path / "out" / "phantoms.json"))[0].orientation == 0


def test_cli_phantom_stl_and_errors(run_less, tmp_path):
    _box_stl(tmp_path / "insert.stl", (50, 50, 25))
    _ball_stl(tmp_path / "ball.stl", 4.0, (0, 0, 3))
    proc = run_less("phantom", "--stl", "insert.stl", "--stl-inclusion", "ball.stl", "--orientations", "0",
                    "--grid-shape", "10,40,40", "--spacing-mm", "1.5,1.5,1.5", "-o", "cad", check=True)
    (row,) = [json.loads(line) for line in proc.stdout.decode().splitlines()]
    assert row["insert"] == "insert" and row["inclusion_voxels"] > 0
    bad = run_less("phantom", "--set", "single", "--names", "St12C31", "-o", "x")
    assert bad.returncode == 1 and b"did you mean 'St12C13'" in bad.stderr and not (tmp_path / "x").exists()
    assert run_less("phantom", "-o", "y").returncode == 2
    missing = run_less("phantom", "--stl", "nope.stl", "-o", "z")
    assert missing.returncode == 1 and b"nope.stl: no such file" in missing.stderr
