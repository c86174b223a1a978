"""The unilateral contact problem on a set of surface nodes.

Given a symmetric positive definite compliance M (mm/N) and the penetration g (mm) of the rigid pad
into the undeformed surface at each node, find nodal forces p >= 0 (N) with

    min 1/2 p^T M p - p^T g,  p >= 0,

i.e. u = M p >= g everywhere (no interpenetration) and u = g where p > 0. A primal-dual active
set iteration (exact on a fixed active set, usually one or two Cholesky solves) runs first; if it
does not settle, non-negative least squares on the Cholesky factor (M = L L^T:
min ||L^T p - L^{-1} g||) gives the answer.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import cholesky, solve_triangular
from scipy.linalg.lapack import dpotrf, dpotrs
from scipy.optimize import nnls

from lesscli.errors import SimulationError

MAX_ACTIVE_SET_ITERS = 25
MAX_CACHED_FACTORS = 64     # Cholesky factors of active-set submatrices kept per compliance
KKT_REL_TOL = 1e-9          # relative tolerance of the optimality check (scale: max |g|)


def cholesky_lower(m: np.ndarray) -> np.ndarray:
    """Lower Cholesky factor of an SPD matrix (LAPACK potrf; the upper triangle holds garbage)."""
    c, info = dpotrf(m, lower=1, clean=0)
    if info != 0:
        raise SimulationError(f"contact compliance on {m.shape[0]} nodes is not positive definite (potrf "
                              f"{info})")
    return c


def cholesky_solve(c: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve with a factor from ``cholesky_lower``."""
    x, _ = dpotrs(c, b, lower=1)
    return x


def kkt_residual(m: np.ndarray, g: np.ndarray, p: np.ndarray) -> float:
    """Largest violation of p >= 0, M p - g >= 0 and complementarity, relative to max |g|."""
    scale = float(np.max(np.abs(g))) or 1.0
    gap = m @ p - g
    return float(max(np.max(-p, initial=0.0) * np.max(np.diag(m)), np.max(-gap, initial=0.0),
                     np.max(np.abs(p * gap), initial=0.0) / max(np.max(p, initial=0.0), 1e-300)) / scale)


def solve_nnls(m: np.ndarray, g: np.ndarray) -> np.ndarray:
    """The contact QP by NNLS on the Cholesky factor (reference method)."""
    lower = cholesky(m, lower=True, check_finite=False)
    b = solve_triangular(lower, g, lower=True, check_finite=False)
    p, _ = nnls(lower.T, b, maxiter=50 * g.size)
    return p


def _factor(m: np.ndarray, idx: np.ndarray, act: np.ndarray, factors: dict | None) -> np.ndarray:
    """``cholesky_lower(M[idx, idx])``, from / into the cache ``factors`` (keyed by ``act``) when given."""
    if factors is None:
        return cholesky_lower(m[np.ix_(idx, idx)])
    key = act.tobytes()
    factor = factors.get(key)
    if factor is None:
        if len(factors) >= MAX_CACHED_FACTORS:
            factors.clear()
        factor = factors[key] = cholesky_lower(m[np.ix_(idx, idx)])
    return factor


def solve_contact(m: np.ndarray, g: np.ndarray, active: np.ndarray | None = None,
                  factors: dict | None = None) -> np.ndarray:
    """Nodal contact forces p (N) >= 0 of the QP above.

    Args:
        m: (k, k) SPD compliance, mm/N.
        g: (k,) penetration, mm (> 0 where the pad is below the undeformed surface).
        active: (k,) bool initial guess of the contact set (default g > 0).
        factors: cache of ``cholesky_lower`` of M's active-set submatrices, keyed by the active
            set's bytes, for this M only (consecutive steps of a press share M and mostly the active
            set); filled here. The factors are those computed without it, so the result is the same.

    Returns:
        (k,) float64 nodal forces, N.
    """
    k = g.size
    if k == 0 or not (g > 0).any():
        return np.zeros(k)
    act = (g > 0) if active is None else active.copy()
    for _ in range(MAX_ACTIVE_SET_ITERS):
        p = np.zeros(k)
        if act.any():
            idx = np.nonzero(act)[0]
            p[idx] = cholesky_solve(_factor(m, idx, act, factors), g[idx])
        gap = m @ p - g
        scale = float(np.max(np.abs(g)))
        new = np.where(act, p > 0, gap < -KKT_REL_TOL * scale)
        if np.array_equal(new, act):
            return p
        act = new
    p = solve_nnls(m, g)
    if kkt_residual(m, g, p) > 1e-6:
        raise SimulationError(f"contact QP did not converge on {k} nodes (KKT residual "
                              f"{kkt_residual(m, g, p):.2e})")
    return p
