"""Small valid objects for tests: random scan sets, label volumes with known geometry, a tiny scene and a
tiny pretraining config; REPO is the repository root (tests run from any folder under tests/)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lesscli.io.labels import LabelVolume
from lesscli.io.scans import ScanSet, default_meta
from lesscli.io.sensor import xela_uscu

REPO = Path(__file__).resolve().parents[1]
GRID_SHAPE = (26, 128, 128)
GRID_SPACING_MM = (0.9, 0.4774, 0.4774)


def example_script(name: str):
    """``examples/<name>.py`` loaded as a module (the scripts are not a package)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(name, REPO / "examples" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def grid_origin(shape=GRID_SHAPE, spacing=GRID_SPACING_MM) -> np.ndarray:
    """Origin that centres the grid on x = y = 0 and puts the top slice at z = 0 (phantom frame)."""
    d, h, w = shape
    dz, dy, dx = spacing
    return np.array([-(d - 1) * dz, -(h - 1) / 2 * dy, -(w - 1) / 2 * dx])


def sphere_labels(center_mm=(-8.0, 3.0, -5.0), radius_mm=6.0, shape=GRID_SHAPE, spacing=GRID_SPACING_MM,
                  name="sphere") -> LabelVolume:
    """Insert everywhere inside |x|,|y| < 28 mm, an inclusion sphere at ``center_mm`` (z, y, x)."""
    origin = grid_origin(shape, spacing)
    z, y, x = np.meshgrid(*(origin[a] + spacing[a] * np.arange(shape[a]) for a in range(3)), indexing="ij")
    data = np.zeros(shape, np.uint8)
    data[(np.abs(x) < 28) & (np.abs(y) < 28)] = 1
    r2 = (z - center_mm[0]) ** 2 + (y - center_mm[1]) ** 2 + (x - center_mm[2]) ** 2
    data[r2 <= radius_mm**2] = 3
    return LabelVolume(data, origin, spacing, name)


def random_scanset(n_scans: int = 2, traj_per_scan: int = 3, max_len: int = 12, seed: int = 0,
                   with_labels: bool = True, inserts: list[str] | None = None) -> ScanSet:
    """A valid scan set with random poses over the phantom and forces that grow with depth."""
    rng = np.random.default_rng(seed)
    lengths = rng.integers(1, max_len + 1, size=n_scans * traj_per_scan)
    n = int(lengths.sum())
    pose = np.zeros((n, 6), np.float32)
    pose[:, :2] = rng.uniform(-25, 25, size=(n, 2))
    pose[:, 2] = -rng.uniform(0, 4, size=n)
    pose[:, 5] = rng.uniform(0, 1.4, size=n)
    force = rng.normal(0, 0.05, size=(n, 30, 3)).astype(np.float32)
    force[..., 2] += -pose[:, 2:3] * 0.5
    time_s = np.concatenate([np.arange(k) * 0.01 for k in lengths])
    inserts = inserts or [f"St{10 + 2 * (i % 3)}C{5 + i}" for i in range(n_scans)]
    labels = [sphere_labels(center_mm=(-8.0, 2.0 * i, -3.0 + i), name=f"{inserts[i]}_0")
              for i in range(n_scans)] \
        if with_labels else []
    return ScanSet(
        pose=pose, force=force, time_s=time_s,
        traj_offsets=np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64),
        traj_scan=np.repeat(np.arange(n_scans), traj_per_scan).astype(np.int64),
        scan_insert=np.array(inserts[:n_scans]), scan_orientation=np.arange(n_scans) % 8,
        scan_label=np.arange(n_scans) if with_labels else -np.ones(n_scans, np.int64),
        labels=labels, meta=default_meta(xela_uscu()),
        traj_attrs={"target_force_n": rng.uniform(1.5, 6, n_scans * traj_per_scan).astype(np.float32)},
    )


def poke_scanset(n_scans: int, seed: int, traj_per_scan: int = 10, steps: int = 5) -> ScanSet:
    """Pokes on a phantom whose stiffness is higher inside one disc per scan.

    Each trajectory presses at one x-y from 0 to a random depth; the 30 x 3 force pattern is a
    fixed profile scaled by depth x stiffness (+ 2 % noise), so forces are predictable from the
    query depth and from what a particle has felt nearby.
    """
    rng = np.random.default_rng(seed)
    profile = np.random.default_rng(99).uniform(0.2, 1.0, size=(30, 3))
    pose, force, lengths, traj_scan = [], [], [], []
    for s in range(n_scans):
        centre = rng.uniform(-12, 12, size=2)
        for _ in range(traj_per_scan):
            xy = rng.uniform(-20, 20, size=2)
            stiff = 3.0 if np.linalg.norm(xy - centre) < 8.0 else 1.0
            depth = np.linspace(0.0, rng.uniform(1.0, 4.0), steps)
            p = np.zeros((steps, 6), np.float32)
            p[:, :2], p[:, 2] = xy, -depth
            f = stiff * depth[:, None, None] * profile[None] * (1 + 0.02 * rng.normal(size=(steps, 30, 3)))
            pose.append(p)
            force.append(f.astype(np.float32))
            lengths.append(steps)
            traj_scan.append(s)
    lengths = np.array(lengths)
    return ScanSet(pose=np.concatenate(pose), force=np.concatenate(force),
                   time_s=np.concatenate([np.arange(n) * 0.5 for n in lengths]),
                   traj_offsets=np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64),
                   traj_scan=np.array(traj_scan, np.int64),
                   scan_insert=np.array([f"St12C{s}" for s in range(n_scans)]),
                   scan_orientation=np.zeros(n_scans, np.int64), scan_label=-np.ones(n_scans, np.int64),
                   meta=default_meta(xela_uscu()))


# A two-insert winkler scene of 3 short pokes per scan, on a coarse label grid (seconds to simulate).
TINY_SCENE = """
name = "tiny"
seed = 3
[phantoms]
set = "single"
names = ["St16C9", "St12D13"]
orientations = [0, 4]
[contact]
tier = "winkler"
[motion]
kind = "poke"
n_traj = 3
approach_mm = [1.0, 1.0]
press_s = [0.2, 0.3]
hold_s = [0.1, 0.1]
[labels]
shape = [6, 16, 16]
spacing_mm = [3.0, 4.0, 4.0]
[effects.tilt]
[effects.sensor]
[effects.noise]
[effects.pose]
"""


def tiny_cfg(**train):
    """A small pretraining config (d_z 16, 8 mm particles over 48 mm, 2 epochs on the CPU); ``train`` sets
    its train.* fields."""
    from lesscli.train.config import PretrainConfig

    cfg = PretrainConfig()
    cfg.model.dim, cfg.model.n_freq, cfg.model.spacing_mm, cfg.model.grid_extent_mm = 16, 4, 8.0, 48.0
    cfg.train.epochs, cfg.train.lr, cfg.train.device = 2, 3e-3, "cpu"
    for k, v in train.items():
        setattr(cfg.train, k, v)
    return cfg
