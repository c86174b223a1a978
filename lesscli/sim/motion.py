"""Motion generators: paper-like poke grids, palpation primitives and hand-held-like paths.

Every generator is ``f(phantom, params, rng, depth_for_force) -> list[Trajectory]`` sampled at
``rate_hz`` (100 Hz by default). Poses are pad poses in the phantom frame: x, y, z mm (z of the pad
face; negative = pressed into the surface at z = 0), roll, pitch, yaw rad. Presses are force
controlled: the indentation for a target force comes from ``depth_for_force`` (the contact tier's
inverse), so a stiff inclusion under the pad gives a shallower press at the same force.
Parameters not given take the values in ``MOTION_DEFAULTS``; ranges are ``[low, high]`` uniform.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from lesscli.phantom.geometry import Phantom

DepthForForce = Callable[[float, float, float, float], float]   # (x_mm, y_mm, yaw_rad, target_n) -> depth mm

_GRID = {"control": "force", "depth_mm": [1.0, 3.0], "n_traj": 100, "spacing_mm": 6.0, "jitter_mm": 1.5,
         "margin_mm": 3.0, "yaw_deg": [0.0, 80.0], "force_n": [1.5, 6.0], "approach_mm": [5.0, 10.0],
         "approach_speed_mm_s": [5.0, 20.0], "press_s": [0.6, 1.2], "hold_s": [0.3, 0.8], "retract_s": 0.4,
         "retract_mm": 3.0, "max_duration_s": 5.0, "rate_hz": 100.0}
MOTION_DEFAULTS: dict[str, dict] = {
    "poke": dict(_GRID),
    "primitive": {**_GRID, "primitives": ["jab", "back_and_forth", "left_and_right"], "slide_mm": [3.0, 10.0],
                  "cycles": [1, 2], "cycle_s": [0.8, 1.4], "tremor_hz": [8.0, 12.0], "tremor_mm": [0.05, 0.3],
                  "force_scale": [0.8, 1.2], "jab_overshoot": [1.1, 1.3], "min_steps": 50,
                  "press_s": [0.4, 0.8], "approach_speed_mm_s": [10.0, 20.0], "approach_mm": [5.0, 8.0]},
    "handheld": {"n_traj": 70, "margin_mm": 3.0, "duration_s": [2.0, 2.9], "force_n": [1.0, 5.0],
                 "force_wobble": 0.3, "path_mm": [4.0, 15.0], "yaw_deg": [0.0, 80.0], "yaw_drift_deg": 10.0,
                 "tilt_deg": 3.0, "approach_mm": [4.0, 6.0], "approach_s": [0.3, 0.5], "retract_s": 0.3,
                 "tremor_hz": [8.0, 12.0], "tremor_mm": [0.05, 0.3], "rate_hz": 100.0, "knots": 6},
}
MIN_HANDHELD_STEPS = 30   # shorter hand-held paths (left the insert early) are redrawn
CONTROLS = ("force", "depth")   # force: press to a target force; depth: press to a drawn depth (no feedback)
DEPTH_KNOTS = 5   # depth_for_force evaluations along a slide, interpolated in between


@dataclass
class Trajectory:
    """One palpation trajectory.

    Attributes:
        time_s: (n,) seconds from 0 at ``rate_hz``.
        pose: (n, 6) pad pose x, y, z mm, roll, pitch, yaw rad, phantom frame.
        attrs: target_force_n, yaw_rad, dx_mm, dy_mm, primitive ('' for pokes).
    """

    time_s: np.ndarray
    pose: np.ndarray
    attrs: dict = field(default_factory=dict)


def min_jerk(n: int) -> np.ndarray:
    """(n,) minimum-jerk profile from 0 to 1 (inclusive ends)."""
    tau = np.linspace(0.0, 1.0, max(n, 2))[:n] if n > 1 else np.ones(1)
    return 10 * tau**3 - 15 * tau**4 + 6 * tau**5


def uniform(rng: np.random.Generator, bounds) -> float:
    """A draw from ``[low, high]`` (or the number itself)."""
    if isinstance(bounds, (int, float)):
        return float(bounds)
    return float(rng.uniform(bounds[0], bounds[1]))


def grid_centres(phantom: Phantom, params: dict, rng: np.random.Generator) -> np.ndarray:
    """(n_traj, 4) jittered, shuffled centres: x, y mm and the jitter dx, dy mm.

    The grid covers the octagon shrunk by ``margin_mm``; if it holds fewer than ``n_traj`` points the
    grid is walked again with fresh jitter.
    """
    a = phantom.apothem_mm - params["margin_mm"]
    step = params["spacing_mm"]
    ticks = np.arange(-math.floor(a / step), math.floor(a / step) + 1) * step
    gx, gy = np.meshgrid(ticks, ticks)
    base = np.stack([gx.ravel(), gy.ravel()], 1)
    base = base[_inside(phantom, base[:, 0], base[:, 1], params["margin_mm"])]
    out = []
    while sum(len(o) for o in out) < params["n_traj"]:
        jit = rng.uniform(-params["jitter_mm"], params["jitter_mm"], size=base.shape)
        xy = base + jit
        ok = _inside(phantom, xy[:, 0], xy[:, 1], params["margin_mm"])
        jit[~ok] = 0.0
        xy = base + jit
        out.append(np.concatenate([xy, jit], 1)[rng.permutation(len(base))])
    return np.concatenate(out)[: params["n_traj"]]


def _inside(phantom: Phantom, x, y, margin_mm: float) -> np.ndarray:
    a = phantom.apothem_mm - margin_mm
    x, y = np.abs(np.asarray(x)), np.abs(np.asarray(y))
    return (x <= a) & (y <= a) & ((x + y) * math.sqrt(0.5) <= a)


def press_profile(depth_mm: float, params: dict, rng: np.random.Generator) -> np.ndarray:
    """(n,) z mm: constant-speed approach from above, minimum-jerk press to -depth, hold, retract."""
    rate = params["rate_hz"]
    height = uniform(rng, params["approach_mm"])
    speed = uniform(rng, params["approach_speed_mm_s"])
    press_n = max(2, round(uniform(rng, params["press_s"]) * rate))
    hold_n = round(uniform(rng, params["hold_s"]) * rate)
    retract_n = max(2, round(params["retract_s"] * rate))
    budget = round(params["max_duration_s"] * rate) - press_n - hold_n - retract_n
    approach_n = max(2, min(round(height / speed * rate), budget))
    approach = speed / rate * np.arange(approach_n)[::-1] + speed / rate
    press = -depth_mm * min_jerk(press_n + 1)[1:]
    hold = np.full(hold_n, -depth_mm)
    retract = -depth_mm + (depth_mm + params["retract_mm"]) * min_jerk(retract_n + 1)[1:]
    return np.concatenate([approach, press, hold, retract])


def _trajectory(x, y, z, yaw, rate_hz: float, attrs: dict, roll=0.0, pitch=0.0) -> Trajectory:
    n = len(z)
    pose = np.zeros((n, 6))
    pose[:, 0], pose[:, 1], pose[:, 2] = x, y, z
    pose[:, 3], pose[:, 4], pose[:, 5] = roll, pitch, yaw
    return Trajectory(np.arange(n) / rate_hz, pose, attrs)


def controlled(p: dict, rng: np.random.Generator, dff: DepthForForce) -> DepthForForce:
    """The press depth rule: the tier's inverse (force control) or a fixed drawn depth (depth control)."""
    if p["control"] == "force":
        return dff
    depth = uniform(rng, p["depth_mm"])
    return lambda x_mm, y_mm, yaw_rad, target_n: depth


def poke_grid(phantom: Phantom, params: dict, rng: np.random.Generator,
              depth_for_force: DepthForForce) -> list[Trajectory]:
    """Paper-like poke grid: one vertical force-controlled press per jittered grid centre."""
    p = {**MOTION_DEFAULTS["poke"], **params}
    out = []
    for x, y, dx, dy in grid_centres(phantom, p, rng):
        yaw = math.radians(uniform(rng, p["yaw_deg"]))
        force = uniform(rng, p["force_n"])
        depth = controlled(p, rng, depth_for_force)(float(x), float(y), yaw, force)
        z = press_profile(depth, p, rng)
        out.append(_trajectory(x, y, z, yaw, p["rate_hz"], {"target_force_n": force, "yaw_rad": yaw,
                                                             "dx_mm": dx, "dy_mm": dy, "primitive": ""}))
    return out


def tremor(n: int, p: dict, rng: np.random.Generator) -> np.ndarray:
    """(n, 3) physiological tremor, 8-12 Hz sinusoids with random phase per axis, mm."""
    t = np.arange(n) / p["rate_hz"]
    freq = rng.uniform(*p["tremor_hz"], size=3)
    amp = rng.uniform(*p["tremor_mm"], size=3)
    phase = rng.uniform(0, 2 * np.pi, size=3)
    return amp * np.sin(2 * np.pi * freq * t[:, None] + phase)


def _primitive(kind: str, x: float, y: float, yaw: float, force: float, p: dict, rng: np.random.Generator,
               dff: DepthForForce) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3) x, y, z path and (n,) slide offset along the primitive's axis, mm."""
    depth = dff(x, y, yaw, force)
    if kind == "jab":
        over = uniform(rng, p["jab_overshoot"])
        z = press_profile(depth * over, {**p, "hold_s": 0.0}, rng)
        settle = -depth * over + depth * (over - 1) * min_jerk(round(0.15 * p["rate_hz"]))
        bottom = int(np.argmin(z))
        z = np.concatenate([z[: bottom + 1], settle, z[bottom + 1:] * depth / (depth * over)])
        return np.stack([np.full(len(z), x), np.full(len(z), y), z], 1), np.zeros(len(z))
    axis = np.array([math.cos(yaw), math.sin(yaw)]) if kind == "left_and_right" else \
        np.array([-math.sin(yaw), math.cos(yaw)])
    amp = uniform(rng, p["slide_mm"])
    cycles = int(rng.integers(p["cycles"][0], p["cycles"][1] + 1))
    slide_n = round(cycles * uniform(rng, p["cycle_s"]) * p["rate_hz"])
    offset = amp * np.sin(2 * np.pi * cycles * np.arange(slide_n) / slide_n)
    knots = np.linspace(-amp, amp, DEPTH_KNOTS)
    depths = np.array([dff(x + k * axis[0], y + k * axis[1], yaw, force) for k in knots])
    z_press = press_profile(depth, {**p, "hold_s": 0.0, "retract_s": 0.0, "retract_mm": 0.0}, rng)
    z_press = z_press[: int(np.argmin(z_press)) + 1]
    z_slide = -np.interp(offset, knots, depths)
    retract_n = max(2, round(p["retract_s"] * p["rate_hz"]))
    z_end = z_slide[-1] + (p["retract_mm"] - z_slide[-1]) * min_jerk(retract_n + 1)[1:]
    z = np.concatenate([z_press, z_slide, z_end])
    off = np.concatenate([np.zeros(len(z_press)), offset, np.full(len(z_end), offset[-1])])
    return np.stack([x + off * axis[0], y + off * axis[1], z], 1), off


def primitives(phantom: Phantom, params: dict, rng: np.random.Generator,
               depth_for_force: DepthForForce) -> list[Trajectory]:
    """Palpation primitives from grid centres; paths that leave the insert are truncated or redrawn."""
    p = {**MOTION_DEFAULTS["primitive"], **params}
    max_n = round(p["max_duration_s"] * p["rate_hz"])
    out = []
    for x, y, dx, dy in grid_centres(phantom, p, rng):
        yaw = math.radians(uniform(rng, p["yaw_deg"]))
        force = uniform(rng, p["force_n"]) * uniform(rng, p["force_scale"])
        for attempt in range(10):
            kind = "jab" if attempt == 9 else str(p["primitives"][int(rng.integers(len(p["primitives"])))])
            path, _ = _primitive(kind, float(x), float(y), yaw, force, p, rng,
                                 controlled(p, rng, depth_for_force))
            path = path[:max_n] + tremor(min(len(path), max_n), p, rng)
            outside = np.flatnonzero(~phantom.inside_outline(path[:, 0], path[:, 1]))
            if len(outside):
                path = path[: outside[0]]
            if len(path) >= min(p["min_steps"], max_n):
                break
        out.append(_trajectory(path[:, 0], path[:, 1], path[:, 2], yaw, p["rate_hz"],
                               {"target_force_n": force, "yaw_rad": yaw, "dx_mm": dx, "dy_mm": dy,
                                "primitive": kind}))
    return out


def _smooth_path(n: int, length_mm: float, rng: np.random.Generator) -> np.ndarray:
    """(n, 2) smooth random planar path from the origin with about ``length_mm`` extent."""
    t = np.linspace(0, 1, n)[:, None]
    freq = rng.uniform(0.3, 1.5, size=(3, 2))
    phase = rng.uniform(0, 2 * np.pi, size=(3, 2))
    wave = sum(np.sin(2 * np.pi * freq[i] * t + phase[i]) - np.sin(phase[i]) for i in range(3))
    scale = np.abs(wave).max() or 1.0
    return wave / scale * length_mm / 2


def handheld(phantom: Phantom, params: dict, rng: np.random.Generator,
             depth_for_force: DepthForForce) -> list[Trajectory]:
    """Hand-held-like palpation: a press, then a smooth wandering slide with force wobble, tilt and tremor."""
    p = {**MOTION_DEFAULTS["handheld"], **params}
    rate, out = p["rate_hz"], []
    while len(out) < p["n_traj"]:
        a = phantom.apothem_mm - p["margin_mm"]
        x0, y0 = rng.uniform(-a, a, size=2)
        if not _inside(phantom, x0, y0, p["margin_mm"]):
            continue
        n = round(uniform(rng, p["duration_s"]) * rate)
        xy = np.array([x0, y0]) + _smooth_path(n, uniform(rng, p["path_mm"]), rng)
        keep = int(np.argmin(_inside(phantom, xy[:, 0], xy[:, 1], p["margin_mm"]))) or n
        if keep < MIN_HANDHELD_STEPS:
            continue
        xy = xy[:keep]
        yaw0, force = math.radians(uniform(rng, p["yaw_deg"])), uniform(rng, p["force_n"])
        t = np.arange(len(xy)) / rate
        yaw = yaw0 + math.radians(p["yaw_drift_deg"]) * np.sin(2 * np.pi * rng.uniform(0.1, 0.5) * t)
        tilt = math.radians(p["tilt_deg"]) * np.sin(2 * np.pi * rng.uniform(0.1, 0.5, size=(2, 1)) * t
                                                     + rng.uniform(0, 2 * np.pi, size=(2, 1)))
        wobble = 1 + p["force_wobble"] * np.sin(2 * np.pi * rng.uniform(0.2, 1.0) * t)
        knots = np.linspace(0, len(xy) - 1, p["knots"]).round().astype(int)
        depth_k = [depth_for_force(float(xy[k, 0]), float(xy[k, 1]), float(yaw[k]), force * wobble[k])
                   for k in knots]
        depth = np.interp(np.arange(len(xy)), knots, depth_k)
        approach_n = round(uniform(rng, p["approach_s"]) * rate)
        z = -depth.copy()
        z[:approach_n] = uniform(rng, p["approach_mm"]) * (1 - min_jerk(approach_n)) - depth[:approach_n] * \
            min_jerk(approach_n)
        retract_n = min(round(p["retract_s"] * rate), len(z) // 3)
        if retract_n > 1:
            z[-retract_n:] = z[-retract_n] + (2.0 - z[-retract_n]) * min_jerk(retract_n)
        pos = np.concatenate([xy, z[:, None]], 1) + tremor(len(z), p, rng)
        out.append(_trajectory(pos[:, 0], pos[:, 1], pos[:, 2], yaw, rate,
                               {"target_force_n": force, "yaw_rad": yaw0, "dx_mm": 0.0, "dy_mm": 0.0,
                                "primitive": "handheld"}, roll=tilt[0], pitch=tilt[1]))
    return out


MOTIONS: dict[str, Callable[[Phantom, dict, np.random.Generator, DepthForForce], list[Trajectory]]] = {
    "poke": poke_grid, "primitive": primitives, "handheld": handheld,
}
