"""Sensor response: per-taxel gain, crosstalk between neighbouring taxels, saturation, counts.

Per scan each taxel axis gets a log-normal gain (``gain_sd``); each taxel picks up ``crosstalk``
times the force of its grid neighbours (centres within 1.1 pitch); every component saturates
smoothly at ``saturation_n`` (S tanh(F / S)); ``counts_per_n`` > 0 converts to sensor counts.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from lesscli.errors import DataError
from lesscli.sim.state import SimState, Stage

DEFAULTS = {"gain_sd": 0.05, "crosstalk": 0.03, "saturation_n": 3.0, "counts_per_n": 0.0}
NEIGHBOUR_FACTOR = 1.1   # taxels closer than this many pitches are neighbours


def validate(params: dict, where: str) -> None:
    if params["gain_sd"] < 0 or not 0 <= params["crosstalk"] < 0.25 or params["saturation_n"] <= 0 \
            or params["counts_per_n"] < 0:
        raise DataError(f"{where}: need gain_sd >= 0, 0 <= crosstalk < 0.25, saturation_n > 0, counts_per_n "
                        ">= 0")


def crosstalk_matrix(taxel_xy_mm: np.ndarray, pitch_mm: float, fraction: float) -> np.ndarray:
    """(T, T) mixing matrix I + fraction * adjacency."""
    d = np.linalg.norm(taxel_xy_mm[:, None] - taxel_xy_mm[None], axis=-1)
    adjacency = (d > 0) & (d < NEIGHBOUR_FACTOR * pitch_mm)
    return np.eye(len(taxel_xy_mm)) + fraction * adjacency


def _sensor(state: SimState, params: dict, rng: np.random.Generator) -> SimState:
    txy = state.taxel_xy_mm
    gain = np.exp(rng.normal(0, params["gain_sd"], size=(len(txy), 3)))
    pitch = state.sensor.get("pitch_mm")
    if pitch is None:                       # the nearest neighbour's distance (a lone taxel has no crosstalk)
        pitch = np.sort(np.linalg.norm(txy - txy[0], axis=1))[1] if len(txy) > 1 else 1.0
    pitch = float(pitch)
    mix = crosstalk_matrix(txy, pitch, params["crosstalk"])
    force = np.einsum("tu,nua->nta", mix, state.force) * gain
    sat = params["saturation_n"]
    force = sat * np.tanh(force / sat)
    units, info = state.force_units, dict(state.info)
    if params["counts_per_n"] > 0:
        force = force * params["counts_per_n"]
        units, info["counts_per_n"] = "counts", float(params["counts_per_n"])
    return replace(state, force=force, force_units=units, info=info)


def stages(params: dict) -> tuple[Stage, ...]:
    return (Stage("sensor", "sensor", "sensor", ("force", "sensor"), ("force", "force_units", "info"),
                  _sensor, params),)
