"""Linear-elastic finite elements of a layered body (scikit-fem, trilinear hexahedra, float64).

The body is any object with the phantom API (``youngs_kpa(points)``, ``inside_outline(x, y)``,
``height_mm``): a structured tensor grid of hexahedra is cut to the outline (elements whose centre
lies inside are kept), the base z = -height_mm is bonded to a rigid support, sides and top are free.
Young's modulus is sampled at every quadrature point, so inclusions and pillars are resolved to the
quadrature, not to whole elements. Units: mm, N, N/mm^2 (= MPa; 1 kPa = 1e-3 N/mm^2).

Trilinear hexahedra lock as nu -> 0.5; Poisson's ratio is capped at ``NU_MAX`` (SIMULATION.md).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from lesscli.errors import SimulationError

NU_MAX = 0.45                  # cap of Poisson's ratio for first-order elements (volumetric locking)
KPA_TO_N_MM2 = 1e-3            # 1 kPa = 1e-3 N/mm^2
COORD_EPS_MM = 1e-9            # tolerance for "on the plane" tests of node coordinates
RHS_CHUNK = 256                # right-hand sides solved at once when building the compliance


@dataclass
class BodyMesh:
    """A hexahedral mesh of the body and its top surface.

    Attributes:
        mesh: skfem ``MeshHex``; ``mesh.p`` (3, nv) vertex coordinates, mm.
        top_nodes: (m,) vertex indices on the top surface z = 0.
        top_xy_mm: (m, 2) their x, y.
        fixed_dofs: dof indices held at zero (base, symmetry planes).
        spacing_mm: nominal in-plane spacing of the top surface.
    """

    mesh: object
    top_nodes: np.ndarray
    top_xy_mm: np.ndarray
    fixed_dofs: np.ndarray
    spacing_mm: float


def uniform_axis(half_mm: float, h_mm: float) -> np.ndarray:
    """Symmetric coordinates k * h covering [-half, half] (odd count, node at 0), mm."""
    n = max(1, math.ceil(half_mm / h_mm - 1e-9))
    return h_mm * np.arange(-n, n + 1, dtype=np.float64)


def graded_axis(length_mm: float, h_fine_mm: float, fine_mm: float, growth: float = 1.25,
                h_max_mm: float | None = None) -> np.ndarray:
    """Coordinates from 0 to ``length_mm``: spacing ``h_fine`` up to ``fine_mm``, then growing geometrically.

    Returns:
        (k,) increasing coordinates starting at 0 and ending exactly at ``length_mm``.
    """
    h_max = h_max_mm if h_max_mm is not None else 8 * h_fine_mm
    xs, h = [0.0], h_fine_mm
    while xs[-1] < length_mm - 1e-9:
        if xs[-1] >= fine_mm - 1e-9:
            h = min(h * growth, h_max)
        xs.append(min(xs[-1] + h, length_mm))
    if len(xs) > 2 and xs[-1] - xs[-2] < 0.3 * h:   # merge a sliver at the end
        xs.pop(-2)
    return np.asarray(xs)


def depth_axis(height_mm: float, h_top_mm: float, skin_mm: float = 0.0, growth: float = 1.3,
               h_max_mm: float = 4.0) -> np.ndarray:
    """z coordinates from -height to 0, fine at the top, with a node at z = -skin_mm when 0 < skin < height.

    Returns:
        (k,) increasing z, mm.
    """
    depth = graded_axis(height_mm, h_top_mm, max(skin_mm, h_top_mm), growth, h_max_mm)
    if 0 < skin_mm < height_mm and np.min(np.abs(depth - skin_mm)) > 1e-6:
        depth = np.sort(np.append(depth, skin_mm))
    return -depth[::-1]


def body_mesh(body, xs_mm: np.ndarray, ys_mm: np.ndarray, zs_mm: np.ndarray,
              symmetry: tuple[str, ...] = ()) -> BodyMesh:
    """Tensor-grid hexahedra cut to the body's outline.

    Args:
        body: object with ``inside_outline(x, y)`` and ``height_mm``.
        xs_mm, ys_mm, zs_mm: increasing grid coordinates; ``zs_mm`` from -height to 0.
        symmetry: planes among ``"x"`` (x = 0, u_x fixed) and ``"y"`` (y = 0, u_y fixed) for
            quarter/half models.

    Returns:
        BodyMesh with the base and symmetry dofs fixed.
    """
    from skfem import MeshHex

    mesh = MeshHex.init_tensor(np.asarray(xs_mm, float), np.asarray(ys_mm, float), np.asarray(zs_mm, float))
    centres = mesh.p[:, mesh.t].mean(axis=1)
    keep = np.asarray(body.inside_outline(centres[0], centres[1]), dtype=bool)
    if not keep.any():
        raise SimulationError("mesh: no element lies inside the body outline")
    if not keep.all():
        mesh = mesh.restrict(np.nonzero(keep)[0])
    p = mesh.p
    top = np.nonzero(np.abs(p[2]) < COORD_EPS_MM)[0]
    fixed = [3 * np.nonzero(np.abs(p[2] - zs_mm[0]) < COORD_EPS_MM)[0][:, None] + np.arange(3)]
    for axis_name, comp in (("x", 0), ("y", 1)):
        if axis_name in symmetry:
            fixed.append(3 * np.nonzero(np.abs(p[comp]) < COORD_EPS_MM)[0][:, None] + comp)
    fixed_dofs = np.unique(np.concatenate([f.ravel() for f in fixed]))
    h = float(np.median(np.diff(xs_mm)))
    return BodyMesh(mesh, top, p[:2, top].T.copy(), fixed_dofs, h)


def modulus_at_quadrature(body, basis) -> np.ndarray:
    """(nelems, nqp) Young's modulus in N/mm^2 at the quadrature points of ``basis``.

    Quadrature points that fall just outside the outline (elements cut by the octagon's diagonals)
    take the modulus at their element's centre.
    """
    x = np.asarray(basis.mapping.F(basis.X))           # (3, ne, nq)
    ne, nq = x.shape[1:]
    e = np.asarray(body.youngs_kpa(x.reshape(3, -1).T), dtype=np.float64).reshape(ne, nq)
    if (e <= 0).any():
        centre = x.mean(axis=2).T
        e_c = np.asarray(body.youngs_kpa(centre), dtype=np.float64)
        rows = np.nonzero((e <= 0).any(axis=1))[0]
        e[rows] = np.where(e[rows] > 0, e[rows], e_c[rows, None])
    if not (np.isfinite(e).all() and (e > 0).all()):
        raise SimulationError("mesh: Young's modulus is not positive and finite at every quadrature point")
    return e * KPA_TO_N_MM2


def stiffness(body, bm: BodyMesh, nu: float) -> sp.csr_matrix:
    """Assemble the global stiffness (3 nv, 3 nv), N/mm, dofs interleaved (3 i + component).

    Args:
        body: phantom-like object (``youngs_kpa``).
        bm: the mesh.
        nu: Poisson's ratio (capped at ``NU_MAX``).
    """
    from skfem import Basis, BilinearForm, ElementHex1, ElementVector, asm
    from skfem.helpers import ddot, sym_grad, trace

    nu = min(float(nu), NU_MAX)
    basis = Basis(bm.mesh, ElementVector(ElementHex1()), intorder=2)
    e = modulus_at_quadrature(body, basis)
    lam_f, mu_f = nu / ((1 + nu) * (1 - 2 * nu)), 1.0 / (2 * (1 + nu))

    @BilinearForm
    def elasticity(u, v, w):
        eu, ev = sym_grad(u), sym_grad(v)
        return w["E"] * (2 * mu_f * ddot(eu, ev) + lam_f * trace(eu) * trace(ev))

    dofs = np.asarray(basis.nodal_dofs)
    if not np.array_equal(dofs, 3 * np.arange(dofs.shape[1]) + np.arange(3)[:, None]):
        raise SimulationError("mesh: unexpected dof numbering of the vector element (expected 3 i + c)")
    return asm(elasticity, basis, E=e).tocsr()


@dataclass
class ReducedSystem:
    """Stiffness with the fixed dofs removed, factorised once.

    Attributes:
        lu: SuperLU factorisation of the free-free block.
        k_ff: the free-free block (csc).
        top_free: (m,) index in the free numbering of each top node's z dof.
    """

    lu: object
    k_ff: sp.csc_matrix
    top_free: np.ndarray


def reduce(k: sp.csr_matrix, bm: BodyMesh) -> ReducedSystem:
    """Remove the fixed dofs and factorise the rest (float64 sparse LU)."""
    n = k.shape[0]
    free = np.setdiff1d(np.arange(n), bm.fixed_dofs)
    index = np.full(n, -1)
    index[free] = np.arange(free.size)
    top_free = index[3 * bm.top_nodes + 2]
    if (top_free < 0).any():
        raise SimulationError("mesh: a top-surface node is fixed; the body needs a free top")
    k_ff = k[free][:, free].tocsc()
    lu = spla.splu(k_ff, permc_spec="MMD_AT_PLUS_A", options={"SymmetricMode": True})
    return ReducedSystem(lu, k_ff, top_free)


def surface_compliance(system: ReducedSystem, nodes: np.ndarray | None = None) -> np.ndarray:
    """Dense compliance of the top surface: C[i, j] = downward displacement at node i per N downward at j.

    Args:
        system: factorised reduced stiffness.
        nodes: subset of top-node positions (indices into ``top_free``); default all.

    Returns:
        (m, m) float64, mm/N, symmetrised (the asymmetry before symmetrising is round-off only).
    """
    cols = system.top_free if nodes is None else system.top_free[np.asarray(nodes)]
    n, m = system.k_ff.shape[0], cols.size
    c = np.empty((m, m))
    for start in range(0, m, RHS_CHUNK):
        block = cols[start:start + RHS_CHUNK]
        rhs = np.zeros((n, block.size))
        rhs[block, np.arange(block.size)] = 1.0
        c[:, start:start + block.size] = system.lu.solve(rhs)[cols]
    return c


def symmetrise(c: np.ndarray) -> tuple[np.ndarray, float]:
    """(C + C^T) / 2 and the relative asymmetry max|C - C^T| / max|C| before it."""
    scale = float(np.max(np.abs(c))) or 1.0
    return 0.5 * (c + c.T), float(np.max(np.abs(c - c.T)) / scale)


def layered_surface_compliance(k: sp.csr_matrix, bm: BodyMesh) -> np.ndarray:
    """Top-surface compliance by eliminating the node layers bottom-up (dense BLAS-3, exact).

    Hexahedra couple only adjacent node layers, so the reduced stiffness is block tridiagonal in
    z: S_1 = K_11, S_{l+1} = K_{l+1,l+1} - K_{l,l+1}^T S_l^{-1} K_{l,l+1}. The last S is the
    stiffness seen at the top surface (all three components); C is the z-z block of its inverse.

    Returns:
        (m, m) float64, mm/N, in the order of ``bm.top_nodes`` (not yet symmetrised).
    """
    from scipy.linalg import cho_factor, cho_solve, cholesky, solve_triangular
    from scipy.linalg.blas import dsyrk

    p = bm.mesh.p
    layer = np.unique(np.round(p[2], 9), return_inverse=True)[1]
    free = np.setdiff1d(np.arange(k.shape[0]), bm.fixed_dofs)
    dof_layer = layer[free // 3]
    groups = [free[dof_layer == v] for v in np.unique(dof_layer)]
    s = k[groups[0]][:, groups[0]].toarray()
    for below, above in itertools.pairwise(groups):
        b = k[below][:, above].toarray()
        x = solve_triangular(cholesky(s, lower=True, check_finite=False), b, lower=True, check_finite=False)
        xtx = dsyrk(1.0, x, trans=1)                       # upper triangle of x^T x
        xtx = np.triu(xtx) + np.triu(xtx, 1).T
        s = k[above][:, above].toarray() - xtx
    top = groups[-1]
    pos = np.searchsorted(top, 3 * bm.top_nodes + 2)
    if not np.array_equal(top[np.minimum(pos, top.size - 1)], 3 * bm.top_nodes + 2):
        raise SimulationError("mesh: the last node layer is not the top surface")
    unit = np.zeros((top.size, pos.size))
    unit[pos, np.arange(pos.size)] = 1.0
    return cho_solve(cho_factor(s, lower=True, check_finite=False), unit, check_finite=False)[pos]


def phantom_mesh(phantom, mesh_mm: float, z_top_mm: float, z_growth: float, z_max_mm: float) -> BodyMesh:
    """The default mesh of an octagonal phantom: uniform in x-y, graded in z, a node layer at the skin."""
    radius = float(phantom.width_mm) / 2 / math.cos(math.pi / 8)
    xs = uniform_axis(radius, mesh_mm)
    zs = depth_axis(float(phantom.height_mm), z_top_mm, float(getattr(phantom, "skin_thickness_mm", 0.0)),
                    z_growth, z_max_mm)
    return body_mesh(phantom, xs, xs, zs)
