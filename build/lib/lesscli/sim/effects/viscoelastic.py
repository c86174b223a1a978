"""Viscoelasticity: a Prony-series relaxation of the elastic per-taxel forces.

Relaxation function g(t) = g_inf + sum_i g_i exp(-t / tau_i) with g_inf = 1 - sum_i g_i. The
viscoelastic force is the hereditary integral f(t) = g_inf f_e(t) + sum_i h_i(t),
h_i(t) = g_i * integral exp(-(t - s) / tau_i) df_e(s), updated exactly for piecewise-linear f_e:
h_i[n] = a_i h_i[n-1] + g_i b_i (f_e[n] - f_e[n-1]), a_i = exp(-dt / tau_i), b_i = tau_i / dt (1 - a_i).
A fast press reads the instantaneous (elastic) force; a hold relaxes towards g_inf of it.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from lesscli.errors import DataError
from lesscli.sim.state import SimState, Stage

DEFAULTS = {"tau_s": [0.5, 5.0], "g": [0.15, 0.1]}


def validate(params: dict, where: str) -> None:
    tau, g = params["tau_s"], params["g"]
    if len(tau) != len(g) or any(t <= 0 for t in tau) or any(x < 0 for x in g) or sum(g) >= 1:
        raise DataError(f"{where}: need tau_s > 0 and g >= 0 of equal length with sum(g) < 1")


def relax(force: np.ndarray, dt_s: float, tau_s, g) -> np.ndarray:
    """(n, ...) elastic force of one trajectory -> viscoelastic force (starts from rest at force[0])."""
    from scipy.signal import lfilter

    df = np.diff(force, axis=0, prepend=np.zeros_like(force[:1]))
    out = (1.0 - float(np.sum(g))) * force
    for tau, gi in zip(tau_s, g):
        a = np.exp(-dt_s / tau)
        b = tau / dt_s * (1 - a)
        out = out + gi * lfilter([b], [1.0, -a], df, axis=0)
    return out


def _viscoelastic(state: SimState, params: dict, rng: np.random.Generator) -> SimState:
    force = np.empty_like(state.force)
    for r in range(len(state.offsets) - 1):
        sl = slice(state.offsets[r], state.offsets[r + 1])
        t = state.time_s[sl]
        dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.01
        force[sl] = relax(state.force[sl], dt, params["tau_s"], params["g"])
    return replace(state, force=force)


def stages(params: dict) -> tuple[Stage, ...]:
    return (Stage("viscoelastic", "viscoelastic", "force", ("force", "offsets", "time_s"), ("force",),
                  _viscoelastic, params),)
