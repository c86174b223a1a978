"""Tier 3 ``fem``: direct finite elements with active-set contact (validation only).

Same mesh, candidate nodes, sensor-skin compliance and taxel sharing as tier 2, but each step
solves the full saddle-point system of the body with the contact constraints of the current active
set (sparse LU, float64) and updates the set until no node penetrates and no contact force pulls:

    [ K    B^T ] [u]   [  0 ]
    [ B   -s I ] [l] = [ -g ]      (u up-positive; l >= 0 nodal contact forces pressing down)

It is the reference for tier 2 on the same mesh (V3) and costs one factorisation per iteration.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from lesscli.errors import SimulationError
from lesscli.sim import fem
from lesscli.sim.contact.green import GreenContact

MAX_ITERS = 30
GAP_REL_TOL = 1e-10        # penetration tolerance relative to max |g| when growing the active set


class FemContact(GreenContact):
    """Tier 3: direct FEM with active-set contact; exact for its mesh, slow."""

    name = "fem"

    def prepare(self, cache_dir: str | None = None) -> None:
        """Mesh and assemble (no compliance, no cache: validation runs are one-off)."""
        if self._prepared:
            return
        bm = self.build_mesh()
        k = fem.stiffness(self.phantom, bm, self.mesh_params()["nu"])
        free = np.setdiff1d(np.arange(k.shape[0]), bm.fixed_dofs)
        index = np.full(k.shape[0], -1)
        index[free] = np.arange(free.size)
        self.k_ff = k[free][:, free].tocsr()
        self.top_free = index[3 * bm.top_nodes + 2]
        self.node_xy = bm.top_xy_mm
        self._setup_steps()
        self._prepared = True

    def solve_nodes(self, idx: np.ndarray, g: np.ndarray, skin: np.ndarray) -> np.ndarray:
        """Active-set direct solve; returns nodal forces (N) on nodes ``idx``."""
        return direct_contact(self.k_ff, self.top_free[idx], g, skin)


def direct_contact(k_ff: sp.csr_matrix, dofs: np.ndarray, g: np.ndarray, skin: np.ndarray) -> np.ndarray:
    """Contact forces on the z dofs ``dofs`` (free numbering) of a body with stiffness ``k_ff``.

    Args:
        k_ff: (nf, nf) stiffness with fixed dofs removed, N/mm.
        dofs: (k,) free-dof index of each candidate node's vertical displacement.
        g: (k,) penetration, mm.
        skin: (k,) series compliance per node, mm/N.

    Returns:
        (k,) nodal forces, N (>= 0).
    """
    nf, k = k_ff.shape[0], g.size
    act = g > 0
    if not act.any():
        return np.zeros(k)
    tol = GAP_REL_TOL * float(np.max(np.abs(g)))
    for _ in range(MAX_ITERS):
        rows = dofs[act]
        na = rows.size
        b = sp.csr_matrix((np.ones(na), (np.arange(na), rows)), shape=(na, nf))
        a = sp.bmat([[k_ff, b.T], [b, -sp.diags(skin[act])]], format="csc")
        sol = spla.spsolve(a, np.concatenate([np.zeros(nf), -g[act]]))
        p = np.zeros(k)
        p[act] = sol[nf:]
        w = -sol[dofs]                               # downward displacement of every candidate
        new = np.where(act, p > 0, w + skin * p - g < -tol)
        if np.array_equal(new, act):
            return p
        act = new
    raise SimulationError(f"contact 'fem': active set did not settle on {k} nodes in {MAX_ITERS} iterations")
