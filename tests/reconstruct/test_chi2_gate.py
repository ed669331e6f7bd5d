"""χ² gates: quantiles per distinct degrees of freedom, equal to scipy's."""

import numpy as np
from scipy.stats import chi2

from scanrig.reconstruct.chi2_gate import chi2_quantile


def test_quantiles_equal_scipys_element_by_element_in_the_shape_of_dof():
    rng = np.random.default_rng(5)
    for shape in [(), (0,), (7,), (3, 4)]:
        for probability in (0.5, 0.999):
            dof = rng.integers(1, 6, size=shape)
            got = chi2_quantile(probability, dof)
            assert got.shape == np.shape(dof)
            np.testing.assert_array_equal(got, chi2.ppf(probability, dof))
    half = np.array([0.5, 1.5, 2.5])  # not only integers
    np.testing.assert_array_equal(chi2_quantile(0.9, half), chi2.ppf(0.9, half))
