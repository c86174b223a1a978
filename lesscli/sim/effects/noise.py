"""Sensor noise: white noise, per-trajectory drift, per-scan offsets, timestamp jitter, baseline removal.

Amplitudes are in newtons (scaled to counts when the sensor effect converted the forces). Sample
instants jitter by N(0, ``jitter_s``) (clipped to +-0.45 sample) and each trajectory's timestamps
restart at 0. With ``baseline`` each trajectory's first force sample is subtracted, as the published
preprocessing does, which removes the offsets.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from lesscli.errors import DataError
from lesscli.sim.state import SimState, Stage

DEFAULTS = {"white_n": 0.005, "drift_n_per_s": 0.01, "offset_n": 0.05, "jitter_s": 0.0005, "baseline": True}
MAX_JITTER_SAMPLES = 0.45


def validate(params: dict, where: str) -> None:
    if min(params["white_n"], params["drift_n_per_s"], params["offset_n"], params["jitter_s"]) < 0:
        raise DataError(f"{where}: noise amplitudes must be >= 0")
    if not isinstance(params["baseline"], bool):
        raise DataError(f"{where}: baseline must be true or false")


def _noise(state: SimState, params: dict, rng: np.random.Generator) -> SimState:
    scale = state.info.get("counts_per_n", 1.0) if state.force_units == "counts" else 1.0
    n, taxels, axes = state.force.shape
    traj = state.traj_index()
    n_traj = len(state.offsets) - 1
    offset = rng.normal(0, params["offset_n"], size=(taxels, axes))
    slope = rng.normal(0, params["drift_n_per_s"], size=(n_traj, taxels, axes))
    white = rng.normal(0, params["white_n"], size=state.force.shape)
    force = state.force + scale * (offset + slope[traj] * state.time_s[:, None, None] + white)
    dt = float(np.median(np.diff(state.time_s))) if n > 1 else 0.01
    jit = np.clip(rng.normal(0, params["jitter_s"], size=n), -MAX_JITTER_SAMPLES * dt,
                  MAX_JITTER_SAMPLES * dt)
    time_s = state.time_s + jit
    firsts = state.offsets[:-1][np.diff(state.offsets) > 0]
    time_s = time_s - np.repeat(time_s[firsts], np.diff(state.offsets)[np.diff(state.offsets) > 0])
    if params["baseline"]:
        force = force - np.repeat(force[firsts], np.diff(state.offsets)[np.diff(state.offsets) > 0], axis=0)
    return replace(state, force=force, time_s=time_s)


def stages(params: dict) -> tuple[Stage, ...]:
    return (Stage("noise", "noise", "noise", ("force", "time_s", "offsets", "info", "force_units"),
                  ("force", "time_s"), _noise, params),)
