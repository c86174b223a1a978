"""Scene -> scan set: determinism, effect isolation, sharding, hard cases, the inclusion signature."""

import numpy as np
import pytest
from sim_spring import SpringTier

from lesscli.errors import SimulationError
from lesscli.io.labels import INCLUSION
from lesscli.io.scans import concat, to_arrays
from lesscli.sim import core
from lesscli.sim.effects import EFFECTS, load_effect
from lesscli.sim.scene import parse_scene
from lesscli.sim.simulate import simulate
from lesscli.sim.state import SimState, Stage

FAST_POKE = {"kind": "poke", "n_traj": 4, "approach_mm": [1.0, 1.0], "approach_speed_mm_s": [20.0, 20.0],
             "press_s": [0.2, 0.3], "hold_s": [0.1, 0.1], "retract_s": 0.1}
SMALL_LABELS = {"shape": [6, 16, 16], "spacing_mm": [3.0, 4.0, 4.0]}


@pytest.fixture
def spring(monkeypatch):
    """Route the scene tier 'spring' to the test-only linear-spring contact."""
    monkeypatch.setattr(core, "contact_tiers", lambda: {"spring": SpringTier})
    core._MODELS.clear()
    yield
    core._MODELS.clear()


def make(effects=None, seed=0, motion=None, phantoms=None, contact=None):
    doc = {"seed": seed,
           "phantoms": phantoms or {"set": "single", "names": ["St16C9"], "orientations": [0, 3]},
           "contact": {"tier": "spring", **(contact or {})},
           "motion": motion if motion and motion.get("kind", "poke") != "poke"
           else {**FAST_POKE, **(motion or {})}, "labels": SMALL_LABELS, "effects": effects or {}}
    return parse_scene(doc, "test.toml")


ALL = {name: {} for name in EFFECTS}


def arrays_equal(a, b, skip=()):
    x, y = to_arrays(a), to_arrays(b)
    assert x.keys() == y.keys()
    return all(np.array_equal(x[k], y[k]) for k in x if k not in skip)


def test_same_seed_is_byte_identical_and_seeds_differ(spring):
    a, b = simulate(make(ALL)), simulate(make(ALL))
    assert arrays_equal(a, b)
    assert all(to_arrays(a)[k].tobytes() == to_arrays(b)[k].tobytes() for k in to_arrays(a))
    c = simulate(make(ALL, seed=1))
    assert not np.array_equal(a.force, c.force) if a.force.shape == c.force.shape else True
    assert a.n_scans == 2 and list(a.scan_orientation) == [0, 3] and set(a.scan_insert) == {"St16C9"}
    assert np.isfinite(a.force).all() and a.force.shape[1:] == (30, 3)


def test_jobs_and_shards_give_the_same_scans(spring):
    scene = make(ALL, phantoms={"set": "single", "limit": 2, "orientations": [0, 5]})
    full = simulate(scene)
    assert arrays_equal(full, simulate(scene, jobs=2))
    parts = [simulate(scene, shard=(i, 3)) for i in range(3)]
    assert [p.n_scans for p in parts] == [1, 2, 1]
    assert arrays_equal(full, concat(parts), skip=("meta",))


def _record_streams(monkeypatch, log):
    """Wrap every effect's stage functions to log the generator state they are handed."""
    for name in EFFECTS:
        module = load_effect(name)
        for attr in [a for a in vars(module) if a.startswith("_") and callable(getattr(module, a))]:
            fn = getattr(module, attr)
            if (getattr(fn, "__code__", None) is None
                or fn.__code__.co_varnames[:3] != ("state", "params", "rng")):
                continue

            def wrapped(state, params, rng, _fn=fn, _key=f"{name}.{attr}"):
                log.setdefault(_key, []).append(repr(rng.bit_generator.state))
                return _fn(state, params, rng)

            monkeypatch.setattr(module, attr, wrapped)


def test_enabling_one_effect_never_changes_another_effects_noise(spring, monkeypatch):
    log = {}
    _record_streams(monkeypatch, log)
    simulate(make({"noise": {}}))
    alone = dict(log)
    log.clear()
    simulate(make(ALL))
    together = dict(log)
    assert set(together) > set(alone)
    assert alone["noise._noise"] and alone["noise._noise"] == together["noise._noise"]
    # end to end: the pose effect only touches poses, so the noisy forces are the same bytes
    a = simulate(make({"noise": {"baseline": False}}))
    b = simulate(make({"noise": {"baseline": False}, "pose": {}}))
    assert np.array_equal(a.force, b.force) and not np.array_equal(a.pose, b.pose)
    clean = simulate(make())
    assert not np.array_equal(a.force, clean.force) and np.array_equal(a.pose, clean.pose)


def test_disabled_effect_is_never_called(spring, monkeypatch):
    shear = load_effect("shear")

    def boom(state, params, rng):
        raise AssertionError("shear ran")

    monkeypatch.setattr(shear, "_shear", boom)
    simulate(make({"noise": {}, "shear": {"enabled": False}}))
    simulate(make({"noise": {}}))
    with pytest.raises(AssertionError, match="shear ran"):
        simulate(make({"shear": {}}))


def test_scene_without_inclusion(spring, tmp_path):
    (tmp_path / "homog.toml").write_text('[[phantom]]\nname = "homog"\n')
    scans = simulate(make(ALL, phantoms={"set": str(tmp_path / "homog.toml"), "orientations": [1]}))
    assert np.isfinite(scans.force).all() and scans.n_traj == 4
    assert not (scans.labels[0].data == INCLUSION).any() and scans.labels[0].data.any()


def test_counts_baseline_and_handheld_tracking(spring):
    effects = {**ALL, "sensor": {"counts_per_n": 100.0}, "pose": {"mode": "handheld"}}
    scans = simulate(make(effects, motion={"kind": "handheld", "n_traj": 3},
                          phantoms={"set": "single", "limit": 1, "orientations": [0]}))
    assert scans.meta["units"]["force"] == "counts"
    firsts = scans.traj_offsets[:-1]
    assert not scans.force[firsts].any()                              # baseline removed
    assert (scans.time_s[firsts] == 0).all() and (np.diff(scans.time_s[firsts[1] - 5:firsts[1]]) > 0).all()
    steps = np.diff(scans.pose[: firsts[1], 0])
    assert 0.2 < np.mean(steps == 0) < 0.8                            # a 30 Hz stream held at 100 Hz
    assert scans.meta["simulation"]["effects"]["pose"]["mode"] == "handheld"


def test_tilt_validity_policies(spring):
    tilt = {"tilt": {"mount_tilt_deg": 5.0, "max_tilt_deg": 0.5}}
    kept = simulate(make(tilt))
    assert kept.meta["simulation"]["flagged_steps"] > 0 and kept.n_traj == 8
    dropped = simulate(make(tilt, contact={"on_invalid": "drop"}))
    assert dropped.meta["simulation"]["dropped_trajectories"] > 0 and dropped.n_traj < 8
    with pytest.raises(SimulationError, match="St16C9 orientation 0 .*trajectory 0 step 0 is outside"):
        simulate(make(tilt, contact={"on_invalid": "error"}))


def test_unknown_tier_suggests(spring):
    from lesscli.errors import DataError

    with pytest.raises(DataError, match="unknown contact tier 'sprung'; did you mean 'spring'"):
        simulate(make(contact={"tier": "sprung"}))


def test_stages_must_declare_what_they_write():
    from lesscli.phantom.geometry import Phantom
    from lesscli.sim.pipeline import run_stages

    state = SimState(0, 0, "x", 0, Phantom("x"), {"taxel_xy_mm": [[0, 0]]}, time_s=np.zeros(1))
    sneaky = Stage("sneaky", "noise", "noise", ("time_s",), ("force",),
                   lambda s, p, r: SimState(**{**s.__dict__, "time_s": np.ones(1)}))
    with pytest.raises(RuntimeError, match=r"sneaky changed \['time_s'\]"):
        run_stages((sneaky,), state)


def test_inclusion_is_visible_in_a_winkler_poke_grid():
    """Presses centred within 5 mm of the inclusion read clearly more force than those > 15 mm away."""
    core._MODELS.clear()
    motion = {**FAST_POKE, "control": "depth", "depth_mm": 2.0, "n_traj": 160, "spacing_mm": 3.5,
              "jitter_mm": 1.0, "yaw_deg": [0.0, 80.0]}
    doc = {"phantoms": {"set": "single", "names": ["St16C9"], "orientations": [2]},
           "contact": {"tier": "winkler"}, "motion": motion, "labels": SMALL_LABELS}
    scene = parse_scene(doc, "visible.toml")
    scans = simulate(scene)
    sphere = scene.phantoms[0].rotated(2).inclusions[0]
    o = scans.traj_offsets
    peak = np.array([scans.force[o[r]:o[r + 1], :, 2].sum(axis=1).max() for r in range(scans.n_traj)])
    dist = np.linalg.norm(scans.pose[o[:-1], :2] - np.array(sphere.center_mm[:2]), axis=1)
    near, far = peak[dist < 5], peak[dist > 15]
    assert len(near) >= 5 and len(far) >= 20
    assert near.mean() > 1.3 * far.mean() and near.mean() > far.mean() + 2 * far.std()


def test_contact_solves_only_distinct_touching_poses_with_identical_results(spring):
    from lesscli.sim.core import solve_contact

    model = SpringTier(make().phantoms[0], make().sensor)
    calls = []
    real = model.solve
    model.solve = lambda pose: calls.append(len(pose)) or real(pose)
    pose = np.zeros((7, 6))
    pose[:, 2] = [3.0, 0.5, -1.0, -1.0, -1.0, -2.0, 0.2]
    pose[:, 3] = [0, 0, 0, 0, 0, 0, 0.3]                 # the last one tilts a pad edge into the surface
    pose[:, 5] = 0.4
    force, depth, flags = solve_contact(model, pose, make().sensor)
    full = real(pose)
    assert calls == [3]                                   # -1 (x3), -2, tilted 0.2
    assert np.array_equal(force, full.force_n) and np.array_equal(depth, full.indentation_mm)
    assert force[6, :, 2].max() > 0 and not force[:2].any()
    assert np.array_equal(flags, full.flags)
