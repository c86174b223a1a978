"""Built-in pipeline stages: contact preparation, motion generation, contact solve, finishing.

Contact is always solved in the insert's own frame (orientation 0): a scan at orientation k rotates
the pad poses by -k * 45 deg instead of rotating the phantom, so the per-phantom precompute of a
contact tier is shared by all eight orientations (the octagon is invariant under 45 deg turns).
"""

from __future__ import annotations

import json
import math
from collections import OrderedDict
from dataclasses import replace

import numpy as np

from lesscli.errors import DataError, SimulationError, did_you_mean
from lesscli.sim.motion import MOTIONS
from lesscli.sim.state import SimState, Stage, rotate_pose

SOLVE_CHUNK = 4096         # pad poses per contact solve call (bounds memory)
MODEL_CACHE_SIZE = 4       # prepared contact models kept per process
FLAG_OUTSIDE_VALIDITY = 1  # same bit as the contact tiers' flag
_MODELS: OrderedDict = OrderedDict()


def contact_tiers() -> dict:
    """The contact tier registry (``lesscli.sim.contact.CONTACT_TIERS``), imported on first use."""
    from lesscli.sim.contact import CONTACT_TIERS

    return CONTACT_TIERS


def scan_label(state: SimState) -> str:
    return f"{state.insert} orientation {state.orientation} (scan {state.scan_index})"


def get_model(tier: str, phantom, sensor: dict, params: dict, cache_dir: str | None):
    """A prepared contact model, memoised per process by tier, params, sensor and phantom content."""
    key = (tier, json.dumps(params, sort_keys=True), json.dumps(sensor, sort_keys=True),
           phantom.content_hash())
    if key in _MODELS:
        _MODELS.move_to_end(key)
        return _MODELS[key]
    tiers = contact_tiers()
    if tier not in tiers:
        raise DataError(f"unknown contact tier '{tier}'{did_you_mean(tier, tiers)}"
                        f" (available: {', '.join(sorted(tiers))})")
    try:
        model = tiers[tier](phantom, sensor, **params)
    except TypeError as exc:
        raise DataError(f"contact tier '{tier}': bad contact.params ({exc})") from None
    model.prepare(cache_dir=cache_dir)
    _MODELS[key] = model
    while len(_MODELS) > MODEL_CACHE_SIZE:
        _MODELS.popitem(last=False)
    return model


def _prepare(state: SimState, params: dict, rng: np.random.Generator) -> SimState:
    return replace(state, model=get_model(params["tier"], state.phantom, state.sensor, params["params"],
                                          params["cache_dir"]))


def _depth_for_force(state: SimState):
    k, model = state.orientation, state.model

    def depth(x_mm: float, y_mm: float, yaw_rad: float, target_n: float) -> float:
        ins = rotate_pose(np.array([[x_mm, y_mm, 0.0, 0.0, 0.0, yaw_rad]]), -k)[0]
        d = float(model.depth_for_force(float(ins[0]), float(ins[1]), float(ins[5]), float(target_n)))
        if not (math.isfinite(d) and d > 0):
            raise SimulationError(f"{scan_label(state)}: depth_for_force({x_mm:.2f}, {y_mm:.2f}, "
                                  f"{yaw_rad:.3f}, {target_n:.2f} N) returned {d}")
        return d

    return depth


def _motion(state: SimState, params: dict, rng: np.random.Generator) -> SimState:
    trajs = MOTIONS[params["kind"]](state.phantom.rotated(state.orientation), params["params"], rng,
                                    _depth_for_force(state))
    if not trajs:
        raise SimulationError(f"{scan_label(state)}: the motion generator produced no trajectories")
    lengths = np.array([len(t.time_s) for t in trajs], dtype=np.int64)
    pose = np.concatenate([t.pose for t in trajs]).astype(np.float64)
    attrs = tuple({k: (v if isinstance(v, str) else float(v)) for k, v in t.attrs.items()} for t in trajs)
    return replace(state, traj_attrs=attrs,
                   offsets=np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64),
                   time_s=np.concatenate([t.time_s for t in trajs]).astype(np.float64), pose_cmd=pose,
                   pose_true=pose, flags=np.zeros(len(pose), np.int64))


def pad_clear_of_surface(pose: np.ndarray, sensor: dict) -> np.ndarray:
    """(n,) bool: every corner of the pad face lies strictly above the surface z = 0 (no contact possible)."""
    from lesscli.sim import kinematics

    txy = np.asarray(sensor["taxel_xy_mm"], dtype=np.float64).reshape(-1, 2)
    size = sensor.get("pad_size_mm") or (np.ptp(txy, axis=0) + float(sensor.get("pitch_mm", 0.0))).tolist()
    return kinematics.pad_corners_mm(pose, size)[..., 2].min(axis=1) > 0.0


def solve_contact(model, pose: np.ndarray, sensor: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Contact for (n, 6) poses, solving only distinct poses that can touch (holds repeat a pose).

    Returns:
        force (n, T, 3) N, indentation (n,) mm, flags (n,) int -- as if every pose had been solved.
    """
    from lesscli.sim import kinematics

    taxels = np.asarray(sensor["taxel_xy_mm"]).reshape(-1, 2).shape[0]
    force = np.zeros((len(pose), taxels, 3))
    depth = np.zeros(len(pose))
    flags = np.where(kinematics.outside_validity(pose), FLAG_OUTSIDE_VALIDITY, 0).astype(np.int64)
    touching = np.flatnonzero(~pad_clear_of_surface(pose, sensor))
    if len(touching) == 0:
        return force, depth, flags
    unique, inverse = np.unique(pose[touching], axis=0, return_inverse=True)
    parts = [model.solve(unique[i:i + SOLVE_CHUNK]) for i in range(0, len(unique), SOLVE_CHUNK)]
    u_force = np.concatenate([np.asarray(r.force_n, dtype=np.float64) for r in parts])
    if u_force.shape[1:] != (taxels, 3):
        raise SimulationError(f"contact tier returned forces of shape {u_force.shape}, expected (n, "
                              f"{taxels}, 3)")
    force[touching] = u_force[inverse.ravel()]
    depth[touching] = np.concatenate([np.asarray(r.indentation_mm, np.float64)
                                      for r in parts])[inverse.ravel()]
    flags[touching] = np.concatenate([np.asarray(r.flags, np.int64) for r in parts])[inverse.ravel()]
    return force, depth, flags


def _contact(state: SimState, params: dict, rng: np.random.Generator) -> SimState:
    pose = rotate_pose(state.pose_true, -state.orientation)
    force, depth, flags = solve_contact(state.model, pose, state.sensor)
    bad = ~np.isfinite(force.reshape(len(pose), -1)).all(axis=1)
    if bad.any():
        step = int(np.flatnonzero(bad)[0])
        traj = int(np.searchsorted(state.offsets, step, side="right") - 1)
        raise SimulationError(f"{scan_label(state)}: non-finite contact force at trajectory {traj}, step "
                              f"{step - state.offsets[traj]} (pose "
                              f"{np.round(state.pose_true[step], 3).tolist()})")
    return replace(state, force=force, indentation_mm=depth, flags=state.flags | flags)


def _finish(state: SimState, params: dict, rng: np.random.Generator) -> SimState:
    pose_out = state.pose_cmd if state.pose_out is None else state.pose_out
    flagged = state.flags & FLAG_OUTSIDE_VALIDITY != 0
    info = {**state.info, "flagged_steps": int(flagged.sum())}
    if flagged.any() and params["on_invalid"] == "error":
        step = int(np.flatnonzero(flagged)[0])
        traj = int(np.searchsorted(state.offsets, step, side="right") - 1)
        raise SimulationError(f"{scan_label(state)}: trajectory {traj} step {step - state.offsets[traj]} is "
                              "outside the contact model's validity (tilt); set contact.on_invalid = 'keep' "
                              "or 'drop' to continue")
    return replace(state, pose_out=pose_out, info=info)


def core_stages(contact: dict, motion: dict) -> dict[str, Stage]:
    """The built-in stages for a scene's contact and motion settings."""
    return {
        "prepare": Stage("core:prepare", "contact", "prepare", ("phantom", "sensor"), ("model",), _prepare,
                         contact),
        "motion": Stage("core:motion", "motion", "motion", ("phantom", "model", "orientation"),
                        ("traj_attrs", "offsets", "time_s", "pose_cmd", "pose_true", "flags"), _motion,
                        motion),
        "contact": Stage("core:contact", "contact", "contact", ("model", "pose_true", "orientation"),
                         ("force", "indentation_mm", "flags"), _contact, contact),
        "finish": Stage("core:finish", "core", "finish", ("pose_cmd", "pose_out", "flags"),
                        ("pose_out", "info"), _finish, contact),
    }
