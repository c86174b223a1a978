"""FEM validation (SIMULATION.md V1, V2, V4, V5) on coarse CI meshes; the fine-mesh checks run in `less bench
sim`."""

import numpy as np
import pytest

from lesscli.io.sensor import grid_layout
from lesscli.phantom import Phantom, Sphere
from lesscli.sim import fem
from lesscli.sim.contact import CONTACT_TIERS
from lesscli.sim.contact import validation as val

E_KPA, NU, RADIUS_MM, HEIGHT_MM, HALF_MM = 15.0, 0.45, 10.0, 20.0, 20.0
DEPTHS_MM = np.array([0.5, 0.6, 0.8, 1.0])
SMALL = grid_layout(4, 4, 3.0, "small-4x4")


@pytest.fixture(scope="module")
def sphere_forces():
    """FEM sphere indentation on a coarse (2 mm) and the CI (1 mm) mesh."""
    return {h: val.sphere_indentation_n(E_KPA, NU, RADIUS_MM, DEPTHS_MM, HEIGHT_MM, HALF_MM, h)
            for h in (2.0, 1.0)}


def test_closed_forms():
    assert val.hertz_force_n(1000.0, 0.0, 1.0, 1.0) == pytest.approx(4 / 3)      # 1 MPa, R = d = 1 mm
    hertz = val.hertz_force_n(E_KPA, NU, RADIUS_MM, 1.0)
    # a thin bonded layer is stiffer than the half-space; a very thick one tends to Hertz
    assert val.dimitriadis_force_n(E_KPA, NU, RADIUS_MM, 1.0, 5.0) > 1.3 * hertz
    assert val.dimitriadis_force_n(E_KPA, NU, RADIUS_MM, 1.0, 1e4) == pytest.approx(hertz, rel=1e-3)
    assert val.flat_punch_force_n(1000.0, 0.0, 4.0, 0.5) == pytest.approx(1.13)


def test_v1_sphere_matches_dimitriadis_and_improves_with_refinement(sphere_forces):
    ref = val.dimitriadis_force_n(E_KPA, NU, RADIUS_MM, DEPTHS_MM, HEIGHT_MM)
    err = {h: np.abs(f / ref - 1) for h, f in sphere_forces.items()}
    assert err[1.0].max() < 0.12
    assert err[1.0].mean() < err[2.0].mean()
    # plain Hertz is clearly low for a 20 mm layer (the layer correction matters)
    assert np.all(sphere_forces[1.0] > 1.08 * val.hertz_force_n(E_KPA, NU, RADIUS_MM, DEPTHS_MM))


def test_v2_small_depth_exponents(sphere_forces):
    slope = np.polyfit(np.log(DEPTHS_MM), np.log(sphere_forces[1.0]), 1)[0]
    assert 1.45 <= slope <= 1.65


def test_v4_compliance_symmetric_positive_definite():
    ph = Phantom("v4", width_mm=30.0, height_mm=12.0, inclusions=(Sphere((3, 2, -5), 3),))
    m = CONTACT_TIERS["green"](ph, SMALL, mesh_mm=3.0, z_top_mm=1.0, z_growth=1.5)
    data = m.compute_compliance()
    assert data["asymmetry"] < 1e-10
    assert np.linalg.eigvalsh(data["c"]).min() > 0


def skfem_stiffness(body, bm, nu):
    """The stiffness by scikit-fem's generic assembly (reference for the box-element assembly)."""
    from skfem import Basis, BilinearForm, ElementHex1, ElementVector, asm
    from skfem.helpers import ddot, sym_grad, trace

    basis = Basis(bm.mesh, ElementVector(ElementHex1()), intorder=2)
    x = np.asarray(basis.mapping.F(basis.X))                    # (3, ne, nq)
    e = np.asarray(body.youngs_kpa(x.reshape(3, -1).T)).reshape(x.shape[1:])
    e = np.where(e > 0, e, np.asarray(body.youngs_kpa(x.mean(axis=2).T))[:, None]) * fem.KPA_TO_N_MM2
    lam, mu = nu / ((1 + nu) * (1 - 2 * nu)), 1 / (2 * (1 + nu))

    @BilinearForm
    def elasticity(u, v, w):
        eu, ev = sym_grad(u), sym_grad(v)
        return w["E"] * (2 * mu * ddot(eu, ev) + lam * trace(eu) * trace(ev))

    return asm(elasticity, basis, E=e).tocsr()


def test_box_assembly_equals_generic_assembly():
    ph = Phantom("asm", width_mm=20.0, height_mm=8.0, inclusions=(Sphere((2, 1, -3), 2.5),))
    bm = fem.phantom_mesh(ph, 2.5, 1.0, 1.5, 3.0)
    ours, ref = fem.stiffness(ph, bm, 0.45), skfem_stiffness(ph, bm, 0.45)
    assert ours.shape == ref.shape and abs(ours - ref).max() < 1e-13 * abs(ref).max()
    assert abs(ours - ours.T).max() < 1e-13 * abs(ref).max()


def test_banded_gram_equals_dense():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(40, 40))
    s = a @ a.T + 40 * np.eye(40)
    b = np.tril(rng.normal(size=(40, 30)), 12)[:, rng.permutation(30)]   # columns zero above varying rows
    b[:, 5] = 0.0
    gram = fem.solve_gram(s, b, block=7)
    np.testing.assert_allclose(gram, b.T @ np.linalg.solve(s, b), rtol=0, atol=1e-12 * np.abs(gram).max())
    assert np.array_equal(gram, gram.T)


def test_layered_elimination_equals_sparse_lu():
    ph = Phantom("lu", width_mm=20.0, height_mm=8.0, inclusions=(Sphere((2, 0, -4), 2),))
    bm = fem.phantom_mesh(ph, 2.5, 1.0, 1.5, 3.0)
    k = fem.stiffness(ph, bm, 0.45)
    a, b = fem.layered_surface_compliance(k, bm), fem.surface_compliance(fem.reduce(k, bm))
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-9 * np.abs(b).max())


def test_v5_green_mesh_convergence(tmp_path):
    ph = Phantom("v5", width_mm=30.0, height_mm=12.0, inclusions=(Sphere((3, 0, -5), 3),))
    pose = np.array([[0.37, 0.21, -1.0, 0, 0, 0.5], [1.1, -0.7, -0.8, 0.05, 0, 1.1], [0, 0, -1.0, 0, 0, 0]])
    forces = []
    for h in (2.0, 1.5):
        m = CONTACT_TIERS["green"](ph, grid_layout(5, 5, 4.0, "square-5x5"), mesh_mm=h, z_top_mm=0.75,
                                   z_growth=1.5)
        m.prepare(cache_dir=str(tmp_path))
        forces.append(m.total_force_n(pose))
    assert np.all(np.abs(forces[1] / forces[0] - 1) < 0.05)


def test_mesh_axes():
    z = fem.depth_axis(30.0, 0.7, 2.0, 1.4, 5.0)
    assert z[0] == pytest.approx(-30.0) and z[-1] == 0.0 and np.any(np.isclose(z, -2.0))
    assert np.all(np.diff(z) > 0) and np.diff(z).max() <= 5.0 + 1e-9
    x = fem.uniform_axis(30.0, 2.0)
    assert x.size % 2 == 1 and x[x.size // 2] == 0.0 and x[-1] >= 30.0
