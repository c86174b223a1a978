"""The randomised training family: draws, validation, scenes, ``less phantom`` and ``less simulate``."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from lesscli.cli.main import cli
from lesscli.errors import DataError
from lesscli.io.labels import BACKGROUND, INCLUSION, PILLAR, load_nifti_labels
from lesscli.io.scans import load_scans
from lesscli.phantom.catalogue import PILLAR_RADIUS_MM, load_phantom_file
from lesscli.phantom.geometry import Phantom
from lesscli.phantom.randomised import (
    RandomRanges,
    family_generator,
    random_family,
    random_set,
    wall_distance_mm,
)
from lesscli.sim.scene import load_scene, parse_scene

FULL_HEIGHT_GRID = ((31, 64, 64), (1.0, 1.0, 1.0))      # z from -30 (the base) to 0, 1 mm voxels
SCENE = """
name = "rnd"
seed = 5
[phantoms]
set = "random"
orientations = [0]
[phantoms.random]
count = 4
[contact]
tier = "winkler"
cache_dir = "{cache}"
[motion]
kind = "poke"
n_traj = 2
[labels]
shape = [13, 64, 64]
spacing_mm = [1.8, 0.9548, 0.9548]
"""


@pytest.fixture(scope="module")
def family():
    return random_set(RandomRanges(count=200, seed=0))


def _spheres(phantoms):
    return [(p, s) for p in phantoms for s in p.inclusions]


def _spans(values, bounds) -> bool:
    """Inside [low, high] and reaching the outer tenth of the range at both ends."""
    low, high = bounds
    tenth = 0.1 * (high - low)
    return low <= np.min(values) < low + tenth and high - tenth < np.max(values) <= high


def test_determinism_by_seed_and_names():
    a, b = random_set(RandomRanges(count=6, seed=7)), random_set(RandomRanges(count=6, seed=7))
    assert a == b and [p.name for p in a] == [f"R{i}s7" for i in range(6)]
    assert random_family(RandomRanges(count=6, seed=7), family_generator(7)) == a
    other = random_set(RandomRanges(count=6, seed=8))
    assert {p.content_hash() for p in a}.isdisjoint(p.content_hash() for p in other)
    assert {p.name for p in a}.isdisjoint(p.name for p in other)
    assert random_set(RandomRanges(count=3, seed=7)) == a[:3]          # count takes a prefix


def test_empty_share_switches_inclusions_only():
    none = random_set(RandomRanges(count=30, empty_share=1.0))
    assert all(not p.inclusions and not p.pillars for p in none)
    one = random_set(RandomRanges(count=30, empty_share=0.0))
    assert all(len(p.inclusions) == 1 and len(p.pillars) == 1 for p in one)
    assert [p.filling for p in none] == [p.filling for p in one]        # the other draws are unchanged
    share = np.mean([not p.inclusions for p in random_set(RandomRanges(count=200))])
    assert 0.05 < share < 0.3


def test_ranges_respected_and_spread(family):
    r = RandomRanges()
    pairs = _spheres(family)
    diameters = np.array([2 * s.radius_mm for _, s in pairs])
    gaps = np.array([-(s.center_mm[2] + s.radius_mm) - p.skin_thickness_mm for p, s in pairs])
    to_wall = np.array([wall_distance_mm(p, *s.center_mm[:2]) - s.radius_mm for p, s in pairs])
    centre_to_wall = np.array([wall_distance_mm(p, *s.center_mm[:2]) for p, s in pairs])
    assert _spans(diameters, r.diameter_mm) and _spans(gaps, r.gap_below_skin_mm)
    for key in ("filling", "inclusion", "skin"):
        assert _spans([getattr(p, key).youngs_kpa for p in family], getattr(r, f"{key}_kpa")), key
    assert to_wall.min() >= r.edge_margin_mm - 1e-9 and to_wall.min() < r.edge_margin_mm + 0.5
    assert (centre_to_wall < 5.0).any() and (centre_to_wall > 25.0).any()   # near the wall and the centre
    xy = np.array([s.center_mm[:2] for _, s in pairs])
    assert (xy.min(axis=0) < -15).all() and (xy.max(axis=0) > 15).all()   # all around, not one family angle


def test_spheres_inside_the_insert_and_pillars_reach_the_base(family):
    r = RandomRanges()
    shrunk = Phantom("margin", width_mm=r.width_mm - 2 * r.edge_margin_mm)
    for p in [q for q in family if q.inclusions][:12]:
        vol = p.label_volume(*FULL_HEIGHT_GRID)
        z, y, x = np.meshgrid(*vol.axes_mm(), indexing="ij")
        (s,) = p.inclusions
        ball = np.linalg.norm(np.stack([x, y, z], -1) - np.array(s.center_mm), axis=-1) <= s.radius_mm - 1e-6
        assert (vol.data[ball] == INCLUSION).all(), p.name                  # nothing of the sphere is clipped
        inc = vol.data == INCLUSION
        assert (vol.data[inc] != BACKGROUND).all() and shrunk.inside_outline(x[inc], y[inc]).all(), p.name
        assert z[inc].max() < -p.skin_thickness_mm and z[inc].min() > -p.height_mm, p.name
        col = (x - s.center_mm[0]) ** 2 + (y - s.center_mm[1]) ** 2 <= (PILLAR_RADIUS_MM - 0.5) ** 2
        below = col & (z <= s.center_mm[2])
        assert col[0].any() and (vol.data[0][col[0]] == PILLAR).all(), p.name          # reaches the base
        assert np.isin(vol.data[below], (PILLAR, INCLUSION)).all(), p.name             # and the sphere


@pytest.mark.parametrize("table, message", [
    ({"diameter_mm": [16, 6]}, "diameter_mm: low 16 is above high 6"),
    ({"diameter_mm": [6, 60]}, "diameter_mm: 60 mm does not fit in the 60 mm insert"),
    ({"gap_below_skin_mm": [1, 20]}, "gap_below_skin_mm: a 16 mm sphere 20 mm under the skin"),
    ({"filling_kpa": [0, 10]}, "filling_kpa must be positive"),
    ({"inclusion_kpa": "stiff"}, "inclusion_kpa must be a finite number"),
    ({"skin_kpa": [1, 2, 3]}, "skin_kpa must be [low, high]"),
    ({"empty_share": 1.5}, "empty_share must lie in [0, 1]"),
    ({"count": 0}, "count must be an integer >= 1"),
    ({"edge_margin_mm": -1}, "edge_margin_mm must be >= 0"),
    ({"diamter_mm": [6, 8]}, "unknown key 'diamter_mm'; did you mean 'diameter_mm'?"),
])
def test_bad_ranges_name_the_key(table, message):
    with pytest.raises(DataError) as exc:
        RandomRanges.from_dict(table, "here")
    assert str(exc.value).startswith("here: ") and message in str(exc.value)


def test_scene_random_set_parses_and_overrides(tmp_path):
    path = tmp_path / "rnd.toml"
    path.write_text(SCENE.format(cache=tmp_path / "cache"))
    scene = load_scene(str(path))
    assert [p.name for p in scene.phantoms] == ["R0s5", "R1s5", "R2s5", "R3s5"]      # seed: the scene's
    assert scene.phantoms == load_scene(str(path)).phantoms
    three = load_scene(str(path), ["phantoms.random.count=3"]).phantoms
    assert [p.name for p in three] == ["R0s5", "R1s5", "R2s5"]
    other = load_scene(str(path), ["phantoms.random.seed=3"]).phantoms
    assert [p.name for p in other] == [f"R{i}s3" for i in range(4)]
    assert other == random_set(RandomRanges(count=4, seed=3))
    fixed = load_scene(str(path), ["phantoms.random.diameter_mm=9", 'phantoms.names=["R2s5"]']).phantoms
    assert [p.name for p in fixed] == ["R2s5"] and all(2 * s.radius_mm == 9 for _, s in _spheres(fixed))
    assert load_scene(str(path), ["phantoms.set=single", "phantoms.limit=1"]).phantoms[0].name == "St8C5"


@pytest.mark.parametrize("random, message", [
    ({"cont": 3}, "s.toml: unknown key 'phantoms.random.cont'; did you mean 'phantoms.random.count'?"),
    ({"diameter_mm": [20, 10]}, "s.toml: phantoms.random: diameter_mm: low 20 is above high 10"),
    ("big", "'phantoms.random' must be a table"),
])
def test_scene_random_errors(random, message):
    with pytest.raises(DataError) as exc:
        parse_scene({"phantoms": {"set": "random", "random": random}}, "s.toml")
    assert message in str(exc.value)
    with pytest.raises(DataError, match="phantoms.set = 'randon' is not known; did you mean 'random'"):
        parse_scene({"phantoms": {"set": "randon"}}, "s.toml")


def test_cli_phantom_random_writes_labels_specs_and_a_set(tmp_path):
    out = tmp_path / "out"
    res = CliRunner().invoke(cli, ["phantom", "--set", "random", "--count", "2", "--seed", "4",
                                   "--random", "empty_share=0", "--orientations", "0,2", "--grid-shape",
                                   "8,32,32", "--spacing-mm", "2,2,2", "-o", str(out), "--format", "jsonl"])
    assert res.exit_code == 0, res.output
    rows = [json.loads(line) for line in res.stdout.splitlines()]
    assert [(r["insert"], r["orientation"]) for r in rows] == [("R0s4", 0), ("R0s4", 2), ("R1s4", 0),
                                                              ("R1s4", 2)]
    assert all(r["inclusion_voxels"] > 0 for r in rows)
    spec = Phantom.from_dict(json.loads((out / "R1s4_2.json").read_text()))
    np.testing.assert_array_equal(load_nifti_labels(str(out / "R1s4_2.nii.gz")).data,
                                  spec.label_volume((8, 32, 32), (2, 2, 2)).data)
    ranges = RandomRanges(count=2, seed=4, empty_share=0.0)
    assert load_phantom_file(str(out / "phantoms.json")) == random_set(ranges)
    bad = CliRunner().invoke(cli, ["phantom", "--set", "single", "--count", "2", "-o", str(tmp_path / "x")])
    assert bad.exit_code == 2 and "--set random" in bad.output


def test_simulate_random_scene_end_to_end(tmp_path):
    (tmp_path / "rnd.toml").write_text(SCENE.format(cache=tmp_path / "cache"))
    scene_args = ["--set", "phantoms.random.count=2", "--set", "phantoms.random.empty_share=0.5"]
    res = CliRunner().invoke(cli, ["simulate", str(tmp_path / "rnd.toml"), "-o", str(tmp_path / "r.npz"),
                                   "--seed", "6", *scene_args])
    assert res.exit_code == 0, res.output
    scans = load_scans(str(tmp_path / "r.npz"))
    phantoms = load_scene(str(tmp_path / "rnd.toml"), [*scene_args[1::2], "seed=6"]).phantoms
    assert list(scans.scan_insert) == ["R0s6", "R1s6"] == [p.name for p in phantoms] and scans.n_traj == 4
    assert np.isfinite(scans.force).all() and np.abs(scans.force).max() > 0
    assert [bool(p.inclusions) for p in phantoms] == [False, True]      # seed 6: one of each
    for i, p in enumerate(phantoms):
        has = (scans.labels[scans.scan_label[i]].data == INCLUSION).any()
        assert has == bool(p.inclusions), p.name


def test_contact_tiers_use_each_phantoms_own_materials(tmp_path):
    from dataclasses import replace

    from lesscli.io.sensor import xela_uscu
    from lesscli.sim.core import get_model

    soft = random_set(RandomRanges(count=1, empty_share=1.0, filling_kpa=10, skin_kpa=100))[0]
    stiff = replace(soft, filling=replace(soft.filling, youngs_kpa=40.0), _cache={})
    assert soft.content_hash() != stiff.content_hash()                 # cache keys see the materials
    models = [get_model("winkler", p, xela_uscu(), {}, str(tmp_path)) for p in (soft, stiff)]
    assert models[0] is not models[1]
    centre = np.zeros((1, 2))
    assert models[1].stiffness_at(centre)[0] > 2 * models[0].stiffness_at(centre)[0]
