"""Pose tracking error: what the recorded pose says about the pad.

- ``robot``: the robot's own reading of the commanded pose, N(0, ``robot_sd_mm``) / N(0, ``robot_sd_rad``)
  per step.
- ``handheld``: an external tracker sees the actual pad (``pose_true``) through a per-scan calibration
  error (rotation N(0, ``calib_deg``) about a random axis, translation N(0, ``calib_mm``)), a per-trajectory
  bias N(0, ``bias_mm``), per-sample jitter (``jitter_mm``, ``jitter_rad``), at ``rate_hz`` (30 Hz) with a
  latency of ``delay_s``; each 100 Hz step holds the latest tracker sample.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from lesscli.errors import DataError
from lesscli.geometry.rotations import rotvec_to_matrix
from lesscli.sim.state import SimState, Stage

DEFAULTS = {"mode": "robot", "robot_sd_mm": 0.1, "robot_sd_rad": 0.001, "calib_mm": 1.0, "calib_deg": 0.5,
            "bias_mm": 0.3, "jitter_mm": 0.45, "jitter_rad": 0.012, "delay_s": 0.03, "rate_hz": 30.0}
MODES = ("robot", "handheld")


def validate(params: dict, where: str) -> None:
    if params["mode"] not in MODES:
        raise DataError(f"{where}: mode must be one of {', '.join(MODES)}, got '{params['mode']}'")
    if params["rate_hz"] <= 0 or params["delay_s"] < 0:
        raise DataError(f"{where}: rate_hz must be > 0 and delay_s >= 0")


def _robot(state: SimState, params: dict, rng: np.random.Generator) -> np.ndarray:
    noise = np.concatenate([rng.normal(0, params["robot_sd_mm"], size=(len(state.pose_cmd), 3)),
                            rng.normal(0, params["robot_sd_rad"], size=(len(state.pose_cmd), 3))], 1)
    return state.pose_cmd + noise


def _handheld(state: SimState, params: dict, rng: np.random.Generator) -> np.ndarray:
    axis = rng.normal(size=3)
    angle_rad = rng.normal(0, math.radians(params["calib_deg"]))
    rot = rotvec_to_matrix(axis / np.linalg.norm(axis) * angle_rad)
    shift = rng.normal(0, params["calib_mm"], size=3)
    out = np.empty_like(state.pose_true)
    for r in range(len(state.offsets) - 1):
        sl = slice(state.offsets[r], state.offsets[r + 1])
        t, true = state.time_s[sl], state.pose_true[sl]
        phase = rng.uniform(0, 1 / params["rate_hz"])
        sample_t = np.maximum(np.floor((t - params["delay_s"] - phase)
                                       * params["rate_hz"]) / params["rate_hz"]
                              + phase, 0.0)
        seen = np.stack([np.interp(sample_t, t, true[:, a]) for a in range(6)], 1)
        idx = np.unique(sample_t, return_inverse=True)[1]
        n_samples = idx.max() + 1
        jitter = np.concatenate([rng.normal(0, params["jitter_mm"], size=(n_samples, 3)),
                                 rng.normal(0, params["jitter_rad"], size=(n_samples, 3))], 1)
        seen[:, :3] = seen[:, :3] @ rot.T + shift + rng.normal(0, params["bias_mm"], size=3)
        out[sl] = seen + jitter[idx]
    return out


def _pose(state: SimState, params: dict, rng: np.random.Generator) -> SimState:
    source = _robot if params["mode"] == "robot" else _handheld
    return replace(state, pose_out=source(state, params, rng))


def stages(params: dict) -> tuple[Stage, ...]:
    return (Stage("pose", "pose", "record", ("pose_cmd", "pose_true", "time_s", "offsets"), ("pose_out",),
                  _pose, params),)
