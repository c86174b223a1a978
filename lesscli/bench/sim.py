"""``less bench sim``: the accuracy-vs-time ladder of the contact tiers.

Checks, each a list of records (error vs reference, time per step, precompute time):

- ``sphere``: FEM rigid-sphere indentation vs Hertz x Dimitriadis (V1) on refining meshes; the
  finest (0.35 mm, full run only) must be within 5 %, the CI mesh (1 mm) within 12 %.
- ``indentation``: a flat pad pressed into a homogeneous insert; each tier vs the finest tier-2 mesh.
- ``inclusion``: a line scan over a single-inclusion insert; each tier's total-force profile vs the
  finest tier-2 mesh (relative L2), signature correlation and peak shift.
- ``scan``: a synthetic 100-trajectory poke scan (100 Hz, <= 5 s each) with the default tier and
  tier 0: seconds per scan after the precompute, and the per-step speed-up of tier 0.
- ``pipeline``: time per simulated frame of ``less simulate`` on a scene (when one is given/found).
"""

from __future__ import annotations

import math
import tempfile
import time
from collections.abc import Iterator

import numpy as np

from lesscli.io.sensor import grid_layout, xela_uscu
from lesscli.phantom import Phantom, Sphere
from lesscli.sim.kinematics import taxel_centres_mm

CHECKS = ("sphere", "indentation", "inclusion", "scan", "pipeline")      # all checks, in the default order

SPHERE = {"e_kpa": 15.0, "nu": 0.45, "radius_mm": 10.0, "height_mm": 20.0, "half_mm": 20.0}
SPHERE_DEPTHS_MM = np.array([0.5, 0.75, 1.0])
V1_CI_MESH_MM, V1_CI_TOL, V1_FINE_MESH_MM, V1_FINE_TOL = 1.0, 0.12, 0.35, 0.05
HZ = 100.0


def _setups(quick: bool) -> dict:
    """Phantoms, sensor and meshes of the ladder."""
    if quick:
        return {"width_mm": 30.0, "height_mm": 12.0, "sensor": grid_layout(4, 4, 3.0, "small-4x4"),
                "meshes": (3.0, 2.0), "ref_mesh": 1.5, "fem_mesh": 3.0, "sphere": Sphere((3, 0, -5), 3),
                "scan_x": np.linspace(-6, 9, 11), "scan_traj": 10, "sphere_meshes": (2.0, V1_CI_MESH_MM)}
    return {"width_mm": 60.0, "height_mm": 30.0, "sensor": xela_uscu(), "meshes": (4.0, 3.0, 2.0),
            "ref_mesh": 1.5, "fem_mesh": 4.0, "sphere": Sphere((8, 0, -10), 6),
            "scan_x": np.linspace(-14, 16, 31), "scan_traj": 100,
            "sphere_meshes": (2.0, V1_CI_MESH_MM, 0.5, V1_FINE_MESH_MM)}


def _model(tier: str, phantom, sensor, cache_dir: str, mesh_mm: float | None = None):
    from lesscli.sim.contact import CONTACT_TIERS

    params = {} if tier == "winkler" else {"mesh_mm": mesh_mm}
    model = CONTACT_TIERS[tier](phantom, sensor, **params)
    t0 = time.perf_counter()
    model.prepare(cache_dir=cache_dir)
    return model, time.perf_counter() - t0


def _timed_solve(model, pose: np.ndarray):
    t0 = time.perf_counter()
    res = model.solve(pose)
    return res, (time.perf_counter() - t0) / len(pose)


def sphere_rows(quick: bool) -> list[dict]:
    """V1: FEM sphere vs Hertz x Dimitriadis on refining meshes."""
    from lesscli.sim.contact import validation as val

    s = SPHERE
    ref = val.dimitriadis_force_n(s["e_kpa"], s["nu"], s["radius_mm"], SPHERE_DEPTHS_MM, s["height_mm"])
    hertz = val.hertz_force_n(s["e_kpa"], s["nu"], s["radius_mm"], SPHERE_DEPTHS_MM)
    rows = []
    for h in _setups(quick)["sphere_meshes"]:
        t0 = time.perf_counter()
        f = val.sphere_indentation_n(s["e_kpa"], s["nu"], s["radius_mm"], SPHERE_DEPTHS_MM, s["height_mm"],
                                     s["half_mm"], h)
        elapsed = time.perf_counter() - t0
        err = float(np.max(np.abs(f / ref - 1)))
        tol = V1_FINE_TOL if h <= V1_FINE_MESH_MM else V1_CI_TOL if h <= V1_CI_MESH_MM else None
        slope = float(np.polyfit(np.log(SPHERE_DEPTHS_MM), np.log(f), 1)[0])
        rows.append({"check": "sphere", "tier": "fem", "mesh_mm": h, "error": err,
                     "reference": "hertz x dimitriadis", "ms_per_step": 1e3 * elapsed / len(f),
                     "precompute_s": None, "pass": None if tol is None else err <= tol, "note":
                     f"exponent {slope:.3f}; plain Hertz off by {float(np.max(np.abs(f / hertz - 1))):.1%}"})
    return rows


def _ladder(quick: bool, cache_dir: str, phantom, pose: np.ndarray, check: str) -> tuple[list[dict], dict]:
    """Every tier/mesh on ``pose``; errors vs the finest green mesh. Returns rows and results by label."""
    cfg = _setups(quick)
    runs = [("green", cfg["ref_mesh"])] + [("green", h) for h in cfg["meshes"]] + \
        [("fem", cfg["fem_mesh"]), ("winkler", None)]
    out, rows = {}, []
    for tier, h in runs:
        model, prep_s = _model(tier, phantom, cfg["sensor"], cache_dir, h)
        res, per_step = _timed_solve(model, pose)
        out[(tier, h)] = res
        rows.append({"check": check, "tier": tier, "mesh_mm": h, "ms_per_step": 1e3 * per_step,
                     "precompute_s": prep_s, "reference": f"green {cfg['ref_mesh']} mm"})
    ref = out[("green", cfg["ref_mesh"])]
    for row in rows:
        res = out[(row["tier"], row["mesh_mm"])]
        row["error"] = float(np.max(np.abs(res.total_n / np.maximum(ref.total_n, 1e-300) - 1)))
        row["map_error"] = float(np.linalg.norm(res.force_n - ref.force_n) / np.linalg.norm(ref.force_n))
    return rows, out


def indentation_rows(quick: bool, cache_dir: str) -> list[dict]:
    """A flat pad on a homogeneous insert: centre, generic tilted/yawed, and deep presses."""
    cfg = _setups(quick)
    ph = Phantom("ladder-plain", width_mm=cfg["width_mm"], height_mm=cfg["height_mm"])
    pose = np.array([[0, 0, -1.0, 0, 0, 0], [1.1, -0.7, -1.5, 0.05, 0.0, 0.6], [0.3, 0.4, -2.5, 0, 0, 1.2]])
    rows, _ = _ladder(quick, cache_dir, ph, pose, "indentation")
    return rows


def inclusion_rows(quick: bool, cache_dir: str) -> list[dict]:
    """A line scan over an inclusion: profile error, signature correlation and peak shift per tier."""
    cfg = _setups(quick)
    plain = Phantom("ladder-plain", width_mm=cfg["width_mm"], height_mm=cfg["height_mm"])
    bump = Phantom("ladder-inclusion", width_mm=cfg["width_mm"], height_mm=cfg["height_mm"],
                   inclusions=(cfg["sphere"],))
    xs = cfg["scan_x"]
    pose = np.zeros((xs.size, 6))
    pose[:, 0], pose[:, 2], pose[:, 5] = xs, -1.5, 0.2
    rows, with_inc = _ladder(quick, cache_dir, bump, pose, "inclusion")
    base = {key: _model(key[0], plain, cfg["sensor"], cache_dir, key[1])[0].solve(pose) for key in with_inc}
    ref_key = ("green", cfg["ref_mesh"])
    taxel_x = taxel_centres_mm(pose, cfg["sensor"])[..., 0]
    bins = np.round(taxel_x - taxel_x.min()).astype(np.int64).ravel()     # 1 mm bins of taxel x
    count = np.bincount(bins)
    seen = count > 0

    def signature(key) -> np.ndarray:
        """Per-taxel force gain from the inclusion, averaged over taxels at the same world x."""
        diff = (with_inc[key].force_n[..., 2] - base[key].force_n[..., 2]).ravel()
        return np.bincount(bins, weights=diff, minlength=count.size)[seen] / count[seen]

    x_axis = (np.arange(count.size) + taxel_x.min())[seen]
    ref_sig = signature(ref_key)
    for row in rows:
        key = (row["tier"], row["mesh_mm"])
        sig = signature(key)
        row["error"] = float(np.linalg.norm(with_inc[key].total_n - with_inc[ref_key].total_n)
                             / np.linalg.norm(with_inc[ref_key].total_n))
        corr = float(np.corrcoef(sig, ref_sig)[0, 1])
        shift = float(abs(x_axis[np.argmax(sig)] - x_axis[np.argmax(ref_sig)]))
        row["note"] = f"taxel signature corr {corr:.3f}, peak shift {shift:.1f} mm"
        row["pass"] = bool(corr >= 0.9 and shift <= 2.0) if row["tier"] == "winkler" else None
    return rows


def synthetic_poke_scan(model, n_traj: int, rng: np.random.Generator, half_mm: float) -> np.ndarray:
    """(n, 6) poses of force-controlled minimum-jerk pokes (100 Hz, <= 5 s each)."""
    poses = []
    for _ in range(n_traj):
        x, y = rng.uniform(-half_mm, half_mm, 2)
        yaw = rng.uniform(0, math.radians(80))
        depth = model.depth_for_force(x, y, yaw, rng.uniform(1.5, 6.0))
        start = rng.uniform(5, 10)
        t_app, t_press, t_hold = start / rng.uniform(5, 20), 1.0, 0.5
        n = [max(2, round(t * HZ)) for t in (t_app, t_press, t_hold, t_press)]
        s = np.linspace(0, 1, n[1])
        jerk = 10 * s ** 3 - 15 * s ** 4 + 6 * s ** 5
        z = np.concatenate([np.linspace(start, 0, n[0]), -depth * jerk, np.full(n[2], -depth),
                            -depth * jerk[::-1]])[: int(5 * HZ)]
        p = np.zeros((z.size, 6))
        p[:, 0], p[:, 1], p[:, 2], p[:, 5] = x, y, z, yaw
        poses.append(p)
    return np.concatenate(poses)


def scan_rows(quick: bool, cache_dir: str) -> list[dict]:
    """Seconds per synthetic 100-trajectory scan: default tier vs tier 0 (per-step speed-up)."""
    cfg = _setups(quick)
    ph = Phantom("ladder-inclusion", width_mm=cfg["width_mm"], height_mm=cfg["height_mm"],
                 inclusions=(cfg["sphere"],))
    green, prep_g = _model("green", ph, cfg["sensor"], cache_dir, None)
    winkler, prep_w = _model("winkler", ph, cfg["sensor"], cache_dir)
    pose = synthetic_poke_scan(green, cfg["scan_traj"], np.random.default_rng(0), cfg["width_mm"] / 4)
    _, g_step = _timed_solve(green, pose)
    _, w_step = _timed_solve(winkler, pose)
    scale = 100.0 / cfg["scan_traj"]
    rows = []
    for tier, step, prep in (("green", g_step, prep_g), ("winkler", w_step, prep_w)):
        rows.append({"check": "scan", "tier": tier,
                     "mesh_mm": green.params["mesh_mm"] if tier == "green" else None,
                     "ms_per_step": 1e3 * step, "precompute_s": prep,
                     "s_per_100_traj": step * len(pose) * scale, "speedup_vs_green": g_step / step,
                     "reference": f"{len(pose)} steps, {cfg['scan_traj']} pokes",
                     "pass": (step * len(pose) * scale < 60.0) if tier == "green" else g_step / step >= 100})
    return rows


def pipeline_rows(scene_path: str | None, quick: bool) -> list[dict]:
    """Time per simulated frame of the default pipeline (one scan, after a warm-up scan)."""
    if scene_path is None:
        return []
    from lesscli.sim.pipeline import compile_pipeline
    from lesscli.sim.scene import load_scene
    from lesscli.sim.simulate import scan_jobs, simulate_scan

    overrides = ["motion.n_traj=10"] if quick else []
    scene = load_scene(scene_path, overrides)
    job = scan_jobs(scene)[0]
    stages = compile_pipeline(scene)
    t0 = time.perf_counter()
    simulate_scan(scene, job, stages)                 # precompute (or cache load) + first scan
    warm = time.perf_counter() - t0
    t0 = time.perf_counter()
    part = simulate_scan(scene, job, stages)
    elapsed = time.perf_counter() - t0
    frames = int(part.lengths.sum())
    return [{"check": "pipeline", "tier": scene.contact["tier"], "mesh_mm": None,
             "ms_per_step": 1e3 * elapsed / max(frames, 1), "precompute_s": warm - elapsed,
             "reference": f"{scene_path}: {frames} frames, {len(part.lengths)} trajectories",
             "s_per_scan": elapsed}]


def run(quick: bool = False, cache_dir: str | None = None, scene_path: str | None = None,
        checks: tuple[str, ...] = CHECKS) -> Iterator[dict]:
    """Yield the ladder records check by check (a fresh temporary cache unless ``cache_dir`` is
    given, so the precompute is timed)."""
    with tempfile.TemporaryDirectory(prefix="less-bench-sim-") as tmp:
        cache = cache_dir or tmp
        table = {"sphere": lambda: sphere_rows(quick), "indentation": lambda: indentation_rows(quick, cache),
                 "inclusion": lambda: inclusion_rows(quick, cache), "scan": lambda: scan_rows(quick, cache),
                 "pipeline": lambda: pipeline_rows(scene_path, quick)}
        for name in checks:
            for row in table[name]():
                yield {"bench": "sim", **row}

