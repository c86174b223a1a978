import numpy as np
import pytest

from lesscli.robust import MAD_TO_SIGMA, robust_sigma


@pytest.mark.parametrize("values, centre, expected", [
    ([1.0, 2.0, 3.0, 4.0, 100.0], None, 1.0 * MAD_TO_SIGMA),    # median 3, deviations 2 1 0 1 97: one outlier
    ([1.0, 2.0, 3.0, 4.0, 100.0], 0.0, 3.0 * MAD_TO_SIGMA),     # about 0: deviations 1 2 3 4 100
    ([5.0, 5.0, 5.0], None, 0.0),                               # no scatter
    ([-2.0, 2.0], None, 2.0 * MAD_TO_SIGMA),                    # median 0 between them
])
def test_robust_sigma_reads_the_median_absolute_deviation(values, centre, expected):
    assert robust_sigma(np.array(values), centre) == pytest.approx(expected)


def test_robust_sigma_reads_normal_scatter_through_outliers():
    rng = np.random.default_rng(3)
    values = np.concatenate([rng.normal(10.0, 2.0, 20_000), np.full(2_000, 1e6)])     # a tenth far out
    assert 2.0 < robust_sigma(values) < 2.5         # the outliers move the median deviation a little, not 1e6
    assert robust_sigma(rng.normal(0.0, 2.0, 20_000)) == pytest.approx(2.0, rel=0.03)
