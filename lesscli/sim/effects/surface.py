"""Where the rig puts the surface: a per-scan height offset and tilt of the phantom's top, a slow baseline
drift.

On a rig the recorded poses are relative to the file's reference pose, not to the phantom's top: per
scan the top sits at ``h(x, y) = offset + b x + c y`` in the recorded frame, with the offset drawn
U(-``offset_mm``, ``offset_mm``) and the tilt U(0, ``tilt_deg``) about a uniformly random horizontal
axis. The contact is solved as before (the pad against the surface); what changes is the recorded pose:
its z gains ``h`` at the pad centre and its roll and pitch the top's slope (to first order, the inverse
of :func:`lesscli.data.surface.to_surface`). The sensor's force baseline drifts slowly over the whole
scan: each taxel's normal force gains ``slope * t_scan`` with the slope N(0, ``drift_n_per_s``) per taxel
and ``t_scan`` the time since the scan's first step (in counts when the sensor effect converted the
forces); it runs before the noise effect, so its baseline removal sees it as a rig's does.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from lesscli.errors import DataError
from lesscli.geometry.rotations import euler_to_matrix
from lesscli.sim.state import SimState, Stage

DEFAULTS = {"offset_mm": 2.0, "tilt_deg": 0.5, "drift_n_per_s": 0.002}


def validate(params: dict, where: str) -> None:
    if min(params["offset_mm"], params["tilt_deg"], params["drift_n_per_s"]) < 0 or params["tilt_deg"] >= 10:
        raise DataError(f"{where}: offset_mm, tilt_deg and drift_n_per_s must be >= 0, tilt_deg below 10")


def scan_time_s(time_s: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """(N,) seconds since the scan's first step, from per-trajectory times and the trajectory offsets."""
    lengths = np.diff(offsets)
    ends = np.asarray(time_s, np.float64)[offsets[1:][lengths > 0] - 1]
    dt = float(np.median(np.diff(time_s))) if len(time_s) > 1 else 0.01
    starts = np.concatenate([[0.0], np.cumsum(ends + dt)[:-1]])
    return time_s + np.repeat(starts, lengths[lengths > 0])


def _drift(state: SimState, params: dict, rng: np.random.Generator) -> SimState:
    scale = state.info.get("counts_per_n", 1.0) if state.force_units == "counts" else 1.0
    slope = rng.normal(0, params["drift_n_per_s"], size=state.force.shape[1])
    force = state.force.copy()
    force[..., 2] += scale * slope[None, :] * scan_time_s(state.time_s, state.offsets)[:, None]
    return replace(state, force=force)


def rig_pose(pose: np.ndarray, offset_mm: float, b: float, c: float) -> np.ndarray:
    """(n, 6) poses relative to a top ``z = 0`` -> the same poses where the top is ``offset + b x + c y``."""
    out = np.array(pose, np.float64)
    out[:, 2] += offset_mm + b * out[:, 0] + c * out[:, 1]
    rot = euler_to_matrix(out[:, 3:])
    r20 = rot[:, 2, 0] + b * rot[:, 0, 0] + c * rot[:, 1, 0]
    r21 = rot[:, 2, 1] + b * rot[:, 0, 1] + c * rot[:, 1, 1]
    out[:, 4] = -np.arcsin(np.clip(r20, -1.0, 1.0))
    out[:, 3] = np.arcsin(np.clip(r21 / np.cos(out[:, 4]), -1.0, 1.0))
    return out


def _record(state: SimState, params: dict, rng: np.random.Generator) -> SimState:
    offset = rng.uniform(-params["offset_mm"], params["offset_mm"])
    tilt, axis = math.tan(math.radians(rng.uniform(0, params["tilt_deg"]))), rng.uniform(0, 2 * math.pi)
    b, c = tilt * math.cos(axis), tilt * math.sin(axis)
    info = {**state.info, "surface": {"offset_mm": round(offset, 4), "b": round(b, 6), "c": round(c, 6)}}
    return replace(state, pose_out=rig_pose(state.pose_out, offset, b, c), info=info)


def stages(params: dict) -> tuple[Stage, ...]:
    return (Stage("surface:drift", "surface", "noise", ("force", "time_s", "offsets", "info", "force_units"),
                  ("force",), _drift, params),
            Stage("surface:record", "surface", "finish", ("pose_out", "info"), ("pose_out", "info"), _record,
                  params))
