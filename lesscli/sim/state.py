"""Simulation state and pipeline stages.

A scan is simulated by threading one immutable ``SimState`` through an ordered tuple of ``Stage``s.
Each stage is a pure function ``f(state, params, rng) -> state`` that declares the fields it reads
and writes; the runner checks that it changed nothing else. Arrays in a state are never modified in
place: a stage builds new arrays and returns ``dataclasses.replace(state, ...)``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, fields

import numpy as np

from lesscli.geometry.rotations import turn_xy
from lesscli.phantom.geometry import Phantom

# Pipeline slots in execution order; every stage sits in one slot.
SLOTS = ("phantom", "prepare", "motion", "pose-true", "contact", "force", "sensor", "noise", "record",
         "finish")
ORIENTATION_STEP_RAD = math.pi / 4


@dataclass(frozen=True)
class SimState:
    """Everything known about one scan while it is simulated.

    Attributes:
        scan_index: global index of the scan in the scene (keys the random streams).
        seed: scene seed.
        insert: insert name.
        orientation: k, insert rotated by k * 45 deg.
        phantom: the insert at orientation 0 (contact is solved in this frame).
        sensor: sensor layout dict (``taxel_xy_mm`` (T, 2) in the pad frame).
        model: the prepared contact model, or None before the prepare slot.
        traj_attrs: per-trajectory attribute dicts.
        offsets: (R+1,) step offsets of the trajectories.
        time_s: (N,) seconds since each trajectory's first step.
        pose_cmd: (N, 6) commanded pad pose, scan frame (x, y, z mm, roll, pitch, yaw rad).
        pose_true: (N, 6) actual pad pose that touches the phantom, scan frame.
        pose_out: (N, 6) recorded pose (what the pose source reports).
        force: (N, T, 3) per-taxel force on the pad (N, or counts after the sensor effect).
        indentation_mm: (N,) max penetration of the pad.
        flags: (N,) int bitmask (contact flags, FLAG_* of the contact tiers).
        force_units: "N" or "counts".
        info: counters for the output meta (e.g. flagged steps).
    """

    scan_index: int
    seed: int
    insert: str
    orientation: int
    phantom: Phantom
    sensor: dict
    model: object | None = None
    traj_attrs: tuple = ()
    offsets: np.ndarray | None = None
    time_s: np.ndarray | None = None
    pose_cmd: np.ndarray | None = None
    pose_true: np.ndarray | None = None
    pose_out: np.ndarray | None = None
    force: np.ndarray | None = None
    indentation_mm: np.ndarray | None = None
    flags: np.ndarray | None = None
    force_units: str = "N"
    info: dict = field(default_factory=dict)

    @property
    def taxel_xy_mm(self) -> np.ndarray:
        """(T, 2) taxel centres in the pad frame, mm."""
        return np.asarray(self.sensor["taxel_xy_mm"], dtype=np.float64).reshape(-1, 2)

    def traj_index(self) -> np.ndarray:
        """(N,) trajectory index of every step."""
        return np.repeat(np.arange(len(self.offsets) - 1), np.diff(self.offsets))


STATE_FIELDS = tuple(f.name for f in fields(SimState))
Stage_fn = Callable[[SimState, dict, np.random.Generator], SimState]


@dataclass(frozen=True)
class Stage:
    """One pure step of the pipeline.

    Attributes:
        name: ``<effect>`` or ``<effect>:<part>`` (core stages use ``core:<part>``).
        effect: the effect that owns the stage ("core" for the built-in ones); keys its RNG stream.
        slot: one of SLOTS.
        reads, writes: SimState field names.
        fn: ``f(state, params, rng) -> state``.
        params: the effect's resolved parameters.
    """

    name: str
    effect: str
    slot: str
    reads: tuple[str, ...]
    writes: tuple[str, ...]
    fn: Stage_fn
    params: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.slot not in SLOTS:
            raise ValueError(f"stage {self.name}: unknown slot '{self.slot}'")
        for name in (*self.reads, *self.writes):
            if name not in STATE_FIELDS:
                raise ValueError(f"stage {self.name}: unknown state field '{name}'")


def rotate_pose(pose: np.ndarray, k: int) -> np.ndarray:
    """(n, 6) poses rotated by k * 45 deg about z (x, y and yaw; roll/pitch are pad-frame angles)."""
    ang = k * ORIENTATION_STEP_RAD
    out = turn_xy(pose, ang)
    out[:, 5] = pose[:, 5] + ang
    return out


def taxel_world_xy(pose: np.ndarray, taxel_xy_mm: np.ndarray) -> np.ndarray:
    """(n, T, 2) taxel centres in the phantom plane for pad poses (n, 6) (tilt neglected), mm."""
    c, s = np.cos(pose[:, 5])[:, None], np.sin(pose[:, 5])[:, None]
    tx, ty = taxel_xy_mm[None, :, 0], taxel_xy_mm[None, :, 1]
    return np.stack([pose[:, 0:1] + c * tx - s * ty, pose[:, 1:2] + s * tx + c * ty], axis=-1)


def per_trajectory(values: np.ndarray, offsets: np.ndarray) -> list[np.ndarray]:
    """Split a per-step array into per-trajectory views."""
    return [values[offsets[r]:offsets[r + 1]] for r in range(len(offsets) - 1)]
