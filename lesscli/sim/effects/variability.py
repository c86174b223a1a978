"""Phantom variability: modulus and skin-thickness jitter between casts, and a stiffness texture.

- Phantom stage: each scan uses one of ``variants`` casts of its insert; a cast scales every region's
  modulus by a log-normal factor (``modulus_sd``) and the skin thickness by N(0, ``thickness_sd_mm``).
  Casts are keyed by (seed, insert, variant), so a contact tier precomputes at most ``variants``
  phantoms per insert (and all orientations share them).
- Force stage: a smooth random multiplicative texture over the surface, a sum of ``texture_modes``
  plane waves with wavelength ``texture_length_mm`` and relative amplitude ``texture_sd``, evaluated at
  each taxel's position.
"""

from __future__ import annotations

import zlib
from dataclasses import replace

import numpy as np

from lesscli.errors import DataError
from lesscli.phantom.geometry import Material
from lesscli.sim.state import SimState, Stage, taxel_world_xy

DEFAULTS = {"modulus_sd": 0.1, "thickness_sd_mm": 0.2, "variants": 2, "texture_sd": 0.05,
            "texture_length_mm": 8.0, "texture_modes": 16}
MIN_THICKNESS_MM = 0.2   # a jittered skin never gets thinner than this


def validate(params: dict, where: str) -> None:
    if int(params["variants"]) < 1 or int(params["texture_modes"]) < 1:
        raise DataError(f"{where}: 'variants' and 'texture_modes' must be at least 1")
    if min(params["modulus_sd"], params["thickness_sd_mm"], params["texture_sd"]) < 0 or \
            params["texture_length_mm"] <= 0:
        raise DataError(f"{where}: standard deviations must be >= 0 and texture_length_mm > 0")


def _cast(state: SimState, params: dict, rng: np.random.Generator) -> SimState:
    variant = int(rng.integers(int(params["variants"])))
    if params["modulus_sd"] == 0 and params["thickness_sd_mm"] == 0:
        return state
    seq = np.random.SeedSequence(state.seed, spawn_key=(zlib.crc32(b"variability-cast"),
                                                         zlib.crc32(state.insert.encode()), variant))
    cast_rng = np.random.Generator(np.random.PCG64(seq))
    p = state.phantom

    def jitter(m: Material) -> Material:
        return Material(m.name, float(m.youngs_kpa * np.exp(cast_rng.normal(0, params["modulus_sd"]))),
                        m.poisson)

    skin, filling, inclusion, pillar = (jitter(m) for m in (p.skin, p.filling, p.inclusion, p.pillar))
    thickness = p.skin_thickness_mm
    if thickness > 0:
        thickness = max(MIN_THICKNESS_MM, thickness + cast_rng.normal(0, params["thickness_sd_mm"]))
    cast = replace(p, skin=skin, filling=filling, inclusion=inclusion, pillar=pillar,
                   skin_thickness_mm=float(thickness), _cache={})
    return replace(state, phantom=cast)


def texture_field(xy_mm: np.ndarray, params: dict, rng: np.random.Generator) -> np.ndarray:
    """(..., 2) positions -> (...) multiplicative stiffness texture, mean 1, sd ~ texture_sd."""
    k = int(params["texture_modes"])
    theta = rng.uniform(0, 2 * np.pi, size=k)
    wavenumber = 2 * np.pi / params["texture_length_mm"] * rng.uniform(0.5, 1.5, size=k)
    phase = rng.uniform(0, 2 * np.pi, size=k)
    vec = np.stack([np.cos(theta), np.sin(theta)], 1) * wavenumber[:, None]
    waves = np.cos(xy_mm @ vec.T + phase)
    return np.clip(1.0 + params["texture_sd"] * np.sqrt(2.0 / k) * waves.sum(-1), 0.0, None)


def _texture(state: SimState, params: dict, rng: np.random.Generator) -> SimState:
    if params["texture_sd"] == 0:
        return state
    scale = texture_field(taxel_world_xy(state.pose_true, state.taxel_xy_mm), params, rng)
    return replace(state, force=state.force * scale[..., None])


def stages(params: dict) -> tuple[Stage, ...]:
    return (Stage("variability:cast", "variability", "phantom", ("phantom", "seed", "insert"), ("phantom",),
                  _cast, params),
            Stage("variability:texture", "variability", "force", ("force", "pose_true", "sensor"), ("force",),
                  _texture, params))
