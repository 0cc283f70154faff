"""Bands, inputs and verification on a model in physical units (a relaxation modulus in
Pa over seconds, 1e9 and 1e-3), started from the docs alone: the delta band equals a
numpy delta-method t-band, the PCE of a user's quantity built on ``to_inputs()`` passes
``mc.verify``, and a level of 95 is refused naming the fix."""

import numpy as np
import pytest
from scipy import stats

from ecfm_uq.chaos import fit_pce
from ecfm_uq.inverse import ModelProblem, fit
from ecfm_uq.mc import verify

T = np.linspace(0.0, 5e-3, 15)  # s
TRUTH = np.array([2.0e9, 1.2e-3])  # Pa, s


def modulus(e, t=T):
    return e[0] * np.exp(-t / e[1])


@pytest.fixture(scope="module")
def res():
    y = modulus(TRUTH) + 1e7 * np.random.default_rng(3).standard_normal(T.size)
    return fit(ModelProblem(modulus, y, names=["E0", "tau"]), [1.0e9, 1.0e-3])


def test_delta_band_in_pascal_is_the_numpy_t_band(res):
    assert res.success, res.message
    t_new = np.array([1e-3, 4e-3])
    band = res.predict(lambda e: modulus(e, t_new), kind="prediction")
    E0, tau = res.eps
    G = np.column_stack([np.exp(-t_new / tau), E0 * t_new / tau**2 * np.exp(-t_new / tau)])
    s2 = res.uncertainty.sigma**2
    var = np.einsum("ij,jk,ik->i", G, res.uncertainty.cov, G) + s2
    half = stats.t.ppf(0.975, T.size - 2) * np.sqrt(var)
    np.testing.assert_allclose(band.upper - band.value, half, rtol=1e-5)
    with pytest.raises(ValueError, match="0.95"):
        res.predict(level=95)


def test_pce_of_a_users_quantity_from_the_fit_passes_verify(res):
    def qoi(e):  # the time at which the modulus falls to 1 GPa, in s
        return np.atleast_1d(e[1] * np.log(e[0] / 1e9))

    pce = fit_pce(qoi, res.uncertainty.to_inputs(), method="quadrature", order=4)
    report = verify(pce, qoi, 2000, seed=0)
    assert np.all(np.abs(report.mean_z) < 4) and np.all(np.abs(report.variance_z) < 4)
    assert np.max(report.holdout_error) < 1e-3
