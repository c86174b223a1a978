"""Linear-elastic finite elements of a layered body (trilinear hexahedra, float64; scikit-fem meshes).

The body is any object with the phantom API (``youngs_kpa(points)``, ``inside_outline(x, y)``,
``height_mm``): a structured tensor grid of hexahedra is cut to the outline (elements whose centre
lies inside are kept), the base z = -height_mm is bonded to a rigid support, sides and top are free.
Young's modulus is sampled at every quadrature point, so inclusions and pillars are resolved to the
quadrature, not to whole elements. The elements are axis-aligned boxes, so the stiffness is assembled
in closed form over all elements at once (``stiffness``). Units: mm, N, N/mm^2 (= MPa; 1 kPa = 1e-3 N/mm^2).

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
GRAM_BLOCK = 256               # columns per block in the banded layer elimination


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


GAUSS = 1.0 / math.sqrt(3.0)     # 2-point Gauss-Legendre abscissa on [-1, 1] (exact for trilinear stiffness)


def box_elements(bm: BodyMesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centres (ne, 3), sizes (ne, 3) mm and corner signs (ne, 8, 3) in {-1, 1} of the mesh's hexahedra.

    Raises:
        SimulationError: an element is not an axis-aligned box (the tensor grids of ``body_mesh`` are).
    """
    corners = np.moveaxis(bm.mesh.p[:, bm.mesh.t], 0, -1)           # (8, ne, 3)
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    centre, size = 0.5 * (lo + hi), hi - lo
    signs = np.where(corners > centre, 1.0, -1.0)
    if not np.allclose(corners, centre + 0.5 * signs * size, rtol=0, atol=COORD_EPS_MM * 1e3) or \
            (size <= 0).any() or len({tuple(s) for s in signs[:, 0].astype(int)}) != 8:
        raise SimulationError("mesh: the stiffness assembly needs axis-aligned box elements")
    return centre, size, np.moveaxis(signs, 0, 1)


def modulus_at_points(body, x_mm: np.ndarray, centre_mm: np.ndarray) -> np.ndarray:
    """(ne, nq) Young's modulus in N/mm^2 at points ``x_mm`` (ne, nq, 3) of elements with ``centre_mm`` (ne,
    3).

    Points that fall just outside the outline (elements cut by the octagon's diagonals) take the
    modulus at their element's centre.
    """
    ne, nq = x_mm.shape[:2]
    e = np.asarray(body.youngs_kpa(x_mm.reshape(-1, 3)), dtype=np.float64).reshape(ne, nq)
    if (e <= 0).any():
        rows = np.nonzero((e <= 0).any(axis=1))[0]
        e_c = np.asarray(body.youngs_kpa(centre_mm[rows]), dtype=np.float64)
        e[rows] = np.where(e[rows] > 0, e[rows], e_c[:, None])
    if not (np.isfinite(e).all() and (e > 0).all()):
        raise SimulationError("mesh: Young's modulus is not positive and finite at every quadrature point")
    return e * KPA_TO_N_MM2


def stiffness(body, bm: BodyMesh, nu: float) -> sp.csr_matrix:
    """Assemble the global stiffness (3 nv, 3 nv), N/mm, dofs interleaved (3 i + component).

    Trilinear box elements, 2 x 2 x 2 Gauss points, Young's modulus sampled at every point:
    K_e[(a, i), (b, j)] = sum_q w_q E_q (lam g_ai g_bj + mu g_aj g_bi + mu delta_ij g_a . g_bj), with
    g_a the shape-function gradients at point q and lam, mu the Lame factors per unit modulus.

    Args:
        body: phantom-like object (``youngs_kpa``).
        bm: the mesh (axis-aligned box elements, as ``body_mesh`` makes).
        nu: Poisson's ratio (capped at ``NU_MAX``).
    """
    nu = min(float(nu), NU_MAX)
    lam, mu = nu / ((1 + nu) * (1 - 2 * nu)), 1.0 / (2 * (1 + nu))
    centre, size, signs = box_elements(bm)
    ne = centre.shape[0]
    xi = GAUSS * np.array(list(itertools.product((-1.0, 1.0), repeat=3)))           # (8 points, 3)
    e = modulus_at_points(body, centre[:, None, :] + 0.5 * xi[None] * size[:, None, :], centre)
    factor = 0.5 * (1.0 + signs[:, None, :, :] * xi[None, :, None, :])               # (ne, q, a, 3)
    grad = np.empty_like(factor)
    for d in range(3):
        others = [o for o in range(3) if o != d]
        grad[..., d] = signs[:, None, :, d] / size[:, None, None, d] * \
            factor[..., others[0]] * factor[..., others[1]]
    weight = e * (np.prod(size, axis=1) / 8.0)[:, None]                               # (ne, q) N/mm^2 mm^3
    flat = grad.reshape(ne, 8, 24)
    t1 = np.matmul(np.swapaxes(flat * weight[..., None], 1, 2), flat).reshape(ne, 8, 3, 8, 3)
    dot = np.einsum("eakbk->eab", t1)
    ke = (lam * t1 + mu * t1.transpose(0, 1, 4, 3, 2) + mu * dot[:, :, None, :, None]
          * np.eye(3)[None, None, :, None, :])
    dofs = (3 * bm.mesh.t.T[:, :, None] + np.arange(3)).reshape(ne, 24)
    n = 3 * bm.mesh.p.shape[1]
    rows = np.broadcast_to(dofs[:, :, None], (ne, 24, 24)).ravel()
    cols = np.broadcast_to(dofs[:, None, :], (ne, 24, 24)).ravel()
    return sp.coo_matrix((ke.reshape(ne, 24, 24).ravel(), (rows, cols)), shape=(n, n)).tocsr()


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


def solve_gram(s: np.ndarray, b: np.ndarray, block: int = GRAM_BLOCK) -> np.ndarray:
    """B^T S^{-1} B for SPD S (n, n) and B (n, k), skipping the leading zeros of B's columns.

    With S = L L^T and X = L^{-1} B, the result is X^T X. A column of B that is zero above row r
    gives a column of X that is zero above row r, so each block of columns is solved on the
    trailing rows only and the Gram blocks are summed over the rows both blocks occupy. For the
    banded couplings of neighbouring node layers (and unit columns) this is about a third of the
    dense cost, with the same sums.

    Returns:
        (k, k) float64, exactly symmetric.
    """
    from scipy.linalg import cholesky, solve_triangular

    lower = cholesky(s, lower=True, check_finite=False)
    nonzero = b != 0
    first = np.where(nonzero.any(axis=0), nonzero.argmax(axis=0), s.shape[0])
    starts = range(0, b.shape[1], block)
    rows = [int(first[j:j + block].min()) for j in starts]
    x = [solve_triangular(lower[r:, r:], b[r:, j:j + block], lower=True, check_finite=False)
         for r, j in zip(rows, starts)]
    gram = np.empty((b.shape[1], b.shape[1]))
    for i, (ri, ji) in enumerate(zip(rows, starts)):
        for j, (rj, jj) in enumerate(zip(rows, starts)):
            if j < i:
                continue
            r = max(ri, rj)
            g = x[i][r - ri:].T @ x[j][r - rj:]
            if i == j:
                g = np.triu(g) + np.triu(g, 1).T
            gram[ji:ji + block, jj:jj + block] = g
            gram[jj:jj + block, ji:ji + block] = g.T
    return gram


def layered_surface_compliance(k: sp.csr_matrix, bm: BodyMesh) -> np.ndarray:
    """Top-surface compliance by eliminating the node layers bottom-up (dense BLAS-3, exact).

    Hexahedra couple only adjacent node layers, so the reduced stiffness is block tridiagonal in
    z: S_1 = K_11, S_{l+1} = K_{l+1,l+1} - K_{l,l+1}^T S_l^{-1} K_{l,l+1}. The last S is the
    stiffness seen at the top surface (all three components); C is the z-z block of its inverse,
    E^T S^{-1} E for the unit columns E of the top nodes' z dofs. Within a layer the nodes are
    numbered row by row, so the coupling K_{l,l+1} is banded (see ``solve_gram``).

    Returns:
        (m, m) float64, mm/N, in the order of ``bm.top_nodes`` (not yet symmetrised).
    """
    p = bm.mesh.p
    layer = np.unique(np.round(p[2], 9), return_inverse=True)[1]
    free = np.setdiff1d(np.arange(k.shape[0]), bm.fixed_dofs)
    dof_layer = layer[free // 3]
    groups = [free[dof_layer == v] for v in np.unique(dof_layer)]
    s = k[groups[0]][:, groups[0]].toarray()
    for below, above in itertools.pairwise(groups):
        s = k[above][:, above].toarray() - solve_gram(s, k[below][:, above].toarray())
    top = groups[-1]
    pos = np.searchsorted(top, 3 * bm.top_nodes + 2)
    if not np.array_equal(top[np.minimum(pos, top.size - 1)], 3 * bm.top_nodes + 2):
        raise SimulationError("mesh: the last node layer is not the top surface")
    order = np.argsort(pos, kind="stable")
    unit = np.zeros((top.size, pos.size))
    unit[pos[order], np.arange(pos.size)] = 1.0
    c = np.empty((pos.size, pos.size))
    c[np.ix_(order, order)] = solve_gram(s, unit)
    return c


def phantom_mesh(phantom, mesh_mm: float, z_top_mm: float, z_growth: float, z_max_mm: float) -> BodyMesh:
    """The default mesh of an octagonal phantom: uniform in x-y, graded in z, a node layer at the skin."""
    radius = float(phantom.width_mm) / 2 / math.cos(math.pi / 8)
    xs = uniform_axis(radius, mesh_mm)
    zs = depth_axis(float(phantom.height_mm), z_top_mm, float(getattr(phantom, "skin_thickness_mm", 0.0)),
                    z_growth, z_max_mm)
    return body_mesh(phantom, xs, xs, zs)
