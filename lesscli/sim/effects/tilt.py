"""Tilt and yaw: the pad's mount is not perfectly aligned with the commanded pose.

Per scan the sensor mount carries a fixed roll/pitch error N(0, ``mount_tilt_deg``) and yaw error
N(0, ``yaw_error_deg``): the pad that touches the phantom (``pose_true``) differs from the commanded
pose, which is what the robot records. Steps whose total tilt (angle between the pad normal and the
vertical) exceeds ``max_tilt_deg`` are flagged as outside the small-slope contact model.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from lesscli.errors import DataError
from lesscli.sim.state import SimState, Stage

DEFAULTS = {"mount_tilt_deg": 1.0, "yaw_error_deg": 0.5, "max_tilt_deg": 30.0}
FLAG_OUTSIDE_VALIDITY = 1


def validate(params: dict, where: str) -> None:
    if params["mount_tilt_deg"] < 0 or params["yaw_error_deg"] < 0 or not 0 < params["max_tilt_deg"] <= 90:
        raise DataError(f"{where}: angles must be >= 0 and max_tilt_deg in (0, 90]")


def tilt_rad(pose: np.ndarray) -> np.ndarray:
    """(n,) angle between the pad normal and the vertical for (n, 6) poses (roll, pitch in rad)."""
    return np.arccos(np.clip(np.cos(pose[:, 3]) * np.cos(pose[:, 4]), -1.0, 1.0))


def _tilt(state: SimState, params: dict, rng: np.random.Generator) -> SimState:
    error = np.zeros(6)
    error[3:5] = rng.normal(0, math.radians(params["mount_tilt_deg"]), size=2)
    error[5] = rng.normal(0, math.radians(params["yaw_error_deg"]))
    pose = state.pose_true + error
    beyond = tilt_rad(pose) > math.radians(params["max_tilt_deg"])
    return replace(state, pose_true=pose, flags=state.flags | np.where(beyond, FLAG_OUTSIDE_VALIDITY, 0))


def stages(params: dict) -> tuple[Stage, ...]:
    return (Stage("tilt", "tilt", "pose-true", ("pose_true", "flags"), ("pose_true", "flags"), _tilt,
                  params),)
