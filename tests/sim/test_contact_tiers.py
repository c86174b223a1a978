"""Contact tiers: API, flags, depth search, cache, and SIMULATION.md V3, V6-V10 on small bodies."""

import math

import numpy as np
import pytest

from lesscli.errors import SimulationError
from lesscli.io.sensor import grid_layout, xela_uscu
from lesscli.phantom import Material, Phantom, Sphere
from lesscli.sim.contact import CONTACT_TIERS, FLAG_OUTSIDE_VALIDITY, FLAG_PAD_OVERHANG, ContactResult

COARSE = {"mesh_mm": 3.0, "z_top_mm": 1.0, "z_growth": 1.5}
SMALL = grid_layout(4, 4, 3.0, "small-4x4")
PARAMS = {"winkler": {}, "green": COARSE, "fem": COARSE}


FILL_KPA = Phantom("defaults").filling.youngs_kpa


def small_phantom(**kw) -> Phantom:
    return Phantom(kw.pop("name", "small"), width_mm=30.0, height_mm=12.0, **kw)


def model(tier, phantom, sensor=SMALL, cache=None, **extra):
    m = CONTACT_TIERS[tier](phantom, sensor, **{**PARAMS[tier], **extra})
    m.prepare(cache_dir=cache)
    return m


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory):
    return str(tmp_path_factory.mktemp("contact-cache"))


def test_registry_and_unknown_parameter():
    assert set(CONTACT_TIERS) == {"winkler", "green", "fem"}
    for tier in CONTACT_TIERS:
        with pytest.raises(SimulationError, match="unknown parameter 'mesh_size'"):
            CONTACT_TIERS[tier](small_phantom(), SMALL, mesh_size=1)


@pytest.mark.parametrize("tier", ["winkler", "green"])
def test_result_shapes_flags_and_depth_for_force(tier, cache_dir):
    m = model(tier, Phantom("mid", width_mm=40.0, height_mm=12.0), sensor=xela_uscu(), cache=cache_dir)
    pose = np.array([[0, 0, 2.0, 0, 0, 0], [0, 0, -1.0, 0, 0, 0.3], [0, 0, -1.0, math.radians(45), 0, 0],
                     [12.0, 0, -1.0, 0, 0, 0]])
    res = m.solve(pose)
    assert isinstance(res, ContactResult)
    assert res.force_n.shape == (4, 30, 3) and res.indentation_mm.shape == (4,) and res.flags.shape == (4,)
    assert np.all(res.force_n[..., :2] == 0) and np.all(res.force_n[0] == 0) and res.indentation_mm[0] == 0
    assert np.all(res.force_n[1:, :, 2] >= 0) and res.total_n[1] > 0
    assert res.indentation_mm[1] == pytest.approx(1.0)
    assert res.flags.tolist()[:2] == [0, 0]
    assert res.flags[2] & FLAG_OUTSIDE_VALIDITY and res.flags[3] & FLAG_PAD_OVERHANG
    depth = m.depth_for_force(2.0, -1.0, 0.4, 0.5)
    got = m.solve(np.array([[2.0, -1.0, -depth, 0, 0, 0.4]])).total_n[0]
    assert got == pytest.approx(0.5, rel=1e-3)
    with pytest.raises(SimulationError, match="x=80.000"):
        m.depth_for_force(80.0, 0.0, 0.0, 1.0)


def test_green_cache_roundtrip(tmp_path):
    ph = small_phantom(inclusions=(Sphere((3, 0, -5), 2.5),))
    first = model("green", ph, cache=str(tmp_path))
    assert first.cache_path is not None and first.cache_path.is_file()
    second = CONTACT_TIERS["green"](ph, SMALL, **COARSE)
    second.compute_compliance = None            # must not be called: the cache answers
    second.prepare(cache_dir=str(tmp_path))
    assert second.cache_path is None
    np.testing.assert_array_equal(first.c, second.c)
    other = model("green", ph.rotated(1), cache=str(tmp_path))      # different content -> different entry
    assert other.cache_path != first.cache_path


def test_v3_green_matches_direct_fem(cache_dir):
    ph = small_phantom(inclusions=(Sphere((4, 0, -5), 3),))
    pose = np.array([[0, 0, -1.0, 0, 0, 0], [3, 1, -1.5, 0.1, 0.2, 0.4], [-4, 2, -0.6, 0, -0.15, 1.0]])
    green, direct = model("green", ph, cache=cache_dir).solve(pose), model("fem", ph).solve(pose)
    rel = np.abs(green.force_n - direct.force_n).max() / np.abs(direct.force_n).max()
    assert rel < 1e-6


def signature(tier, xs, cache):
    ph0 = Phantom("plain", width_mm=40.0, height_mm=15.0)
    ph1 = Phantom("bump", width_mm=40.0, height_mm=15.0, inclusions=(Sphere((5, 0, -6), 4),))
    pose = np.zeros((xs.size, 6))
    pose[:, 0], pose[:, 2] = xs, -1.0
    extra = {"mesh_mm": 2.5} if tier == "green" else {}
    return model(tier, ph1, cache=cache, **extra).total_force_n(pose) - \
        model(tier, ph0, cache=cache, **extra).total_force_n(pose)


def test_v6_winkler_signature_tracks_green(cache_dir):
    xs = np.linspace(-10, 14, 25)
    s0, s2 = signature("winkler", xs, cache_dir), signature("green", xs, cache_dir)
    assert s0.max() > 0 and s2.max() > 0
    assert np.corrcoef(s0, s2)[0, 1] >= 0.9
    assert abs(xs[np.argmax(s0)] - xs[np.argmax(s2)]) <= 2.0


def test_v7_force_monotone_and_saturating_in_contrast(cache_dir):
    forces = []
    for contrast in (20.0, 1000.0, 1e5):
        ph = small_phantom(inclusion=Material("inc", FILL_KPA * contrast),
                           inclusions=(Sphere((0, 0, -5), 3),))
        forces.append(model("green", ph, cache=cache_dir).total_force_n(np.array([[0, 0, -1.0, 0, 0, 0]]))[0])
    f20, f1k, f1e5 = forces
    assert np.isfinite(forces).all() and f20 <= f1k <= f1e5
    # saturating: the gain per decade of contrast shrinks, and the last 100x adds less than 25 %
    assert (f1e5 - f1k) / math.log(100) < (f1k - f20) / math.log(50)
    assert f1e5 < 1.25 * f1k


@pytest.mark.parametrize("tier", ["winkler", "green"])
def test_v8_exact_limits(tier, cache_dir):
    pose = np.array([[1.0, -2.0, -1.2, 0.05, 0, 0.3], [0, 0, 0.0, 0, 0, 0], [0, 0, 0.5, 0.05, 0, 0]])
    plain = model(tier, small_phantom(), cache=cache_dir).solve(pose)
    matched = small_phantom(inclusion=Material("same", FILL_KPA), inclusions=(Sphere((2, 0, -5), 3),))
    deep = small_phantom(inclusions=(Sphere((2, 0, -40), 3),))
    for ph in (matched, deep):
        np.testing.assert_allclose(model(tier, ph, cache=cache_dir).solve(pose).force_n, plain.force_n,
                                   rtol=1e-12, atol=0)
    assert np.all(plain.force_n[1:] == 0)       # touching or above the surface: exactly zero


@pytest.mark.parametrize("tier", ["winkler", "green"])
def test_v9_yaw_90_permutes_taxel_map(tier, cache_dir):
    sensor = grid_layout(5, 5, 4.0, "square-5x5")
    m = model(tier, small_phantom(), sensor=sensor, cache=cache_dir)
    xy = np.asarray(sensor["taxel_xy_mm"])
    a = m.solve(np.array([[2.0, 1.0, -1.0, 0, 0, 0]])).force_n[0, :, 2]
    b = m.solve(np.array([[-1.0, 2.0, -1.0, 0, 0, math.pi / 2]])).force_n[0, :, 2]
    assert a.max() > 0
    np.testing.assert_allclose(b, a, rtol=1e-9, atol=1e-12 * a.max())   # the whole scene turned by 90 deg
    # at the centre, the yaw-0 map seen in the world frame is the yaw-90 map with taxels permuted
    c = m.solve(np.array([[0, 0, -1.0, 0, 0, 0], [0, 0, -1.0, 0, 0, math.pi / 2]])).force_n[:, :, 2]
    rot = np.stack([-xy[:, 1], xy[:, 0]], 1)
    # yaw-90 taxel i sits where perm[i] was
    perm = np.argmin(np.abs(rot[:, None] - xy[None]).sum(-1), axis=1)
    np.testing.assert_allclose(c[1], c[0][perm], rtol=1e-9, atol=1e-12 * c.max())


@pytest.mark.parametrize("tier", ["winkler", "green"])
def test_v10_hard_cases_finite_or_named_error(tier, cache_dir):
    pose = np.array([[0, 0, 3.0, 0, 0, 0], [0, 0, -1e-4, 0, 0, 0], [0, 0, -1.0, math.radians(80), 0, 0]])
    cases = [small_phantom(),
             small_phantom(inclusions=(Sphere((0, 0, -3.0), 3.0),)),          # touching the skin
             small_phantom(inclusion=Material("hard", FILL_KPA * 1e5), inclusions=(Sphere((0, 0, -5), 3),))]
    for ph in cases:
        res = model(tier, ph, cache=cache_dir).solve(pose)
        assert np.isfinite(res.force_n).all() and np.isfinite(res.indentation_mm).all()
        assert np.all(res.force_n[0] == 0) and res.total_n[1] > 0
        assert res.flags[2] & FLAG_OUTSIDE_VALIDITY and not res.flags[1] & FLAG_OUTSIDE_VALIDITY
    m = model(tier, small_phantom(), cache=cache_dir)
    with pytest.raises(SimulationError, match="sample 1"):
        m.solve(np.array([[0, 0, -1.0, 0, 0, 0], [0, 0, np.inf, 0, 0, 0]]))


def test_v2_flat_pad_force_is_linear_in_depth(cache_dir):
    m = model("green", small_phantom(), cache=cache_dir)
    d = np.array([0.05, 0.1, 0.2])
    pose = np.zeros((3, 6))
    pose[:, 2] = -d
    f = m.total_force_n(pose)
    slopes = np.diff(np.log(f)) / np.diff(np.log(d))
    np.testing.assert_allclose(slopes, 1.0, atol=1e-6)


def test_flat_pad_rim_taxels_read_more_than_centre(cache_dir):
    m = model("green", Phantom("wide", width_mm=60.0, height_mm=20.0), sensor=xela_uscu(), cache=cache_dir)
    grid = m.solve(np.array([[0, 0, -1.0, 0, 0, 0]])).force_n[0, :, 2].reshape(5, 6)
    assert grid[0, 0] > 1.5 * grid[2, 2:4].mean()


def test_winkler_press_shortcut_equals_per_sample_path(monkeypatch, cache_dir):
    from lesscli.sim.contact import winkler

    ph = small_phantom(inclusions=(Sphere((3, 0, -5), 3),))
    z = np.linspace(1.0, -2.0, 40)                     # approach, partial and full contact of a tilted pad
    pose = np.zeros((80, 6))
    pose[:40, 0], pose[:40, 2], pose[:40, 3], pose[:40, 5] = 1.0, z, 0.06, 0.4
    pose[40:, 0], pose[40:, 1], pose[40:, 2], pose[40:, 4] = 8.0, 3.0, z, -0.05   # overhangs the edge
    grouped = model("winkler", ph).solve(pose)
    monkeypatch.setattr(winkler, "GROUP_MIN", 10 ** 9)
    direct = model("winkler", ph).solve(pose)
    np.testing.assert_allclose(grouped.force_n, direct.force_n, rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(grouped.flags, direct.flags)
    np.testing.assert_allclose(grouped.indentation_mm, direct.indentation_mm, rtol=1e-12, atol=0)
    assert (grouped.flags & FLAG_PAD_OVERHANG).any() and grouped.total_n.max() > 0
