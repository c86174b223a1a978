"""Phantom geometry: regions, outline, rotation, labels, serialisation."""

import json
import math

import numpy as np
import pytest

from lesscli.errors import DataError
from lesscli.io.labels import BACKGROUND, INCLUSION, INSERT, PILLAR
from lesscli.phantom.geometry import Material, Phantom, Pillar, Sphere, label_grid_origin


def one_inclusion(x=13.0, y=0.0, z=-10.0, r=6.0, name="St12C13") -> Phantom:
    return Phantom(name, inclusions=(Sphere((x, y, z), r),), pillars=(Pillar(x, y, z, 1.5),))


def test_classify_hand_picked_points():
    p = one_inclusion()
    pts = np.array([
        [13.0, 0.0, -10.0],    # inclusion centre
        [13.0, 0.0, -25.0],    # pillar below the inclusion
        [0.0, 0.0, -1.0],      # skin
        [0.0, 0.0, -20.0],     # filling
        [0.0, 0.0, 1.0],       # above the top
        [0.0, 0.0, -31.0],     # below the base
        [29.0, 29.0, -5.0],    # outside the octagon's diagonal flat
        [29.0, 0.0, -5.0],     # inside near a straight flat
    ])
    assert p.classify(pts).tolist() == [INCLUSION, PILLAR, INSERT, INSERT, BACKGROUND, BACKGROUND,
                                        BACKGROUND, INSERT]
    e = p.youngs_kpa(pts)
    assert e.tolist() == [p.inclusion.youngs_kpa, p.pillar.youngs_kpa, p.skin.youngs_kpa,
                          p.filling.youngs_kpa, 0.0, 0.0, 0.0, p.skin.youngs_kpa * 0 + p.filling.youngs_kpa]


def test_outline_is_regular_octagon_with_flats_at_half_width():
    p = Phantom("h", width_mm=60.0)
    v = p.outline_xy()
    assert v.shape == (8, 2)
    radii = np.linalg.norm(v, axis=1)
    np.testing.assert_allclose(radii, 30.0 / math.cos(math.pi / 8))
    assert p.inside_outline(30.0, 0.0) and not p.inside_outline(30.01, 0.0)
    d = 30.0 * math.sqrt(0.5)  # on the diagonal flat
    assert p.inside_outline(d, d) and not p.inside_outline(d + 0.01, d + 0.01)
    # every vertex lies on the boundary
    assert p.inside_outline(v[:, 0], v[:, 1]).all()
    assert not p.inside_outline(v[:, 0] * 1.001, v[:, 1] * 1.001).any()


def test_rotation_is_absolute_and_exact_for_quarter_turns():
    p = one_inclusion()
    q = p.rotated(2)
    assert q.orientation == 2 and q.name == p.name
    assert q.inclusions[0].center_mm == (0.0, 13.0, -10.0)
    assert q.pillars[0].x_mm == 0.0 and q.pillars[0].y_mm == 13.0
    assert q.rotated(0) == p
    r = p.rotated(1)
    np.testing.assert_allclose(r.inclusions[0].center_mm[:2], [13 * math.sqrt(0.5)] * 2)
    assert p.rotated(3).rotated(5) == p.rotated(5)
    assert p.rotated(8) == p


def test_label_volume_grid_and_rotation_permutes_labels():
    p = one_inclusion()
    vol = p.label_volume()
    assert vol.shape == (26, 128, 128) and vol.data.dtype == np.uint8
    np.testing.assert_allclose(vol.origin_mm, label_grid_origin((26, 128, 128), (0.9, 0.4774, 0.4774)))
    assert vol.origin_mm[0] + 25 * 0.9 == pytest.approx(0.0)
    assert set(np.unique(vol.data)) == {0, 1, 2, 3}
    # inclusion centroid at (x, y) = (13, 0) mm
    z, y, x = np.nonzero(vol.data == INCLUSION)
    zc, yc, xc = (vol.origin_mm + vol.spacing_mm * np.stack([z, y, x], 1)).mean(0)
    assert (xc == pytest.approx(13.0, abs=0.3) and yc == pytest.approx(0.0, abs=0.3)
            and zc == pytest.approx(-10, abs=0.5))
    # a quarter turn (x -> y) is a transpose-and-flip of the in-plane axes on this symmetric grid
    rot = p.rotated(2).label_volume()
    assert rot.name == "St12C13_2"
    np.testing.assert_array_equal(rot.data, np.flip(np.swapaxes(vol.data, 1, 2), axis=2))


def test_label_volume_custom_grid():
    vol = Phantom("big", width_mm=120).label_volume(shape=(4, 16, 20), spacing_mm=(1.0, 8.0, 8.0))
    assert vol.shape == (4, 16, 20)
    assert (vol.data[:, 8, 10] == INSERT).all() and not vol.data[:, 0, 0].any()  # corners outside the octagon
    assert vol.data[:, 8, 2].all() and not vol.data[:, 8, 1].any()  # x = -56 mm inside, x = -64 mm outside


def test_region_priority_and_skin_touching_inclusion():
    p = Phantom("touch", inclusions=(Sphere((0, 0, -5.0), 5.0),), pillars=(Pillar(0, 0, -5.0, 1.0),))
    pts = np.array([[0, 0, -0.0], [0, 0, -1.0], [0, 0, -5.0], [0, 0, -20.0], [3, 3, -1.0]])
    assert p.classify(pts).tolist() == [INCLUSION, INCLUSION, INCLUSION, PILLAR, INSERT]


def test_no_inclusion_is_homogeneous_layers():
    p = Phantom("homog", skin_thickness_mm=0.0)
    pts = np.array([[0, 0, -0.0], [5, 5, -15.0], [-20, 10, -29.9]])
    assert (p.youngs_kpa(pts) == p.filling.youngs_kpa).all()
    assert np.isinf(p.inclusion_sdf_mm(pts)).all()


def test_dict_roundtrip_through_json_and_hash():
    p = one_inclusion().rotated(3)
    d = json.loads(json.dumps(p.to_dict()))
    q = Phantom.from_dict(d)
    assert q == p and q.content_hash() == p.content_hash()
    assert p.content_hash() == one_inclusion(name="other").rotated(3).content_hash()  # name excluded
    assert p.content_hash() != one_inclusion().content_hash()
    stiffer = Phantom.from_dict({**d, "inclusion": {"name": "x", "youngs_kpa": 900.0}})
    assert stiffer.content_hash() != p.content_hash()


@pytest.mark.parametrize("bad, message", [
    ({"name": "a", "widht_mm": 60}, "did you mean 'width_mm'"),
    ({"name": "a", "inclusions": [{"center_mm": [0, 0, -5], "radius": 2}]}, "did you mean 'radius_mm'"),
    ({"name": "a", "inclusions": [{"center_mm": [0, 0, -5], "radius_mm": -2}]}, "radius_mm must be positive"),
    ({"name": "a", "height_mm": 0}, "height_mm must be positive"),
    ({"name": "a", "skin": {"name": "s", "youngs_kpa": 10, "poisson": 0.5}}, "poisson"),
    ({"width_mm": 60}, "missing 'name'"),
    ({"name": "a", "inclusions": [{"center_mm": [0, 0, -5]}]}, "missing key"),
])
def test_from_dict_errors_name_the_problem(bad, message):
    with pytest.raises(DataError, match=message):
        Phantom.from_dict(bad, where="spec.json")


def test_material_validation():
    with pytest.raises(DataError):
        Material("m", 0.0)
    assert Material("m", 5.0).poisson == 0.45
