"""The unilateral contact QP: active set vs NNLS on the Cholesky factor, KKT conditions, edge cases."""

import numpy as np

from lesscli.io.sensor import grid_layout
from lesscli.sim.contact import PadGeometry
from lesscli.sim.contact.qp import kkt_residual, solve_contact, solve_nnls


def compliance(rng: np.random.Generator, k: int) -> np.ndarray:
    """A dense SPD kernel like a surface compliance: positive, decaying with distance."""
    xy = rng.uniform(0, 10, (k, 2))
    d = np.linalg.norm(xy[:, None] - xy[None], axis=-1)
    return 1.0 / (1.0 + d) + 0.05 * np.eye(k)


def test_active_set_matches_nnls_on_partial_contact():
    rng = np.random.default_rng(3)
    for _ in range(5):
        m = compliance(rng, 40)
        g = rng.normal(0.0, 1.0, 40)          # mixed signs: some nodes cannot touch
        p_as, p_ref = solve_contact(m, g), solve_nnls(m, g)
        assert np.all(p_as >= 0) and kkt_residual(m, g, p_as) < 1e-9
        np.testing.assert_allclose(p_as, p_ref, atol=1e-8 * max(1.0, p_ref.max()))


def test_no_penetration_gives_exact_zero():
    m = compliance(np.random.default_rng(0), 10)
    assert np.all(solve_contact(m, -np.abs(np.arange(10.0))) == 0)
    assert solve_contact(np.zeros((0, 0)), np.zeros(0)).shape == (0,)


def test_share_splits_loads_by_overlap():
    pad = PadGeometry.from_sensor(grid_layout(2, 1, 4.0, "two"))     # cells x in [-4, 0] and [0, 4]
    cells, weights = pad.share(np.array([[-2.0, 0.0], [0.5, 0.0], [-5.0, 0.0]]), 2.0)
    np.testing.assert_allclose(weights.sum(axis=1), 1.0)
    share = np.zeros((3, 2))
    np.add.at(share, (np.repeat(np.arange(3), cells.shape[1]), cells.ravel()), weights.ravel())
    np.testing.assert_allclose(share, [[1.0, 0.0], [0.25, 0.75], [1.0, 0.0]])
