"""Field outputs through principal components (PCA-PCE): exact compression bookkeeping,
and indices that agree with one sparse fit per output component."""

import numpy as np
import pytest
from scipy import stats

from ecfm_uq.chaos import fit_pce
from ecfm_uq.chaos.regression.compression import compress_outputs

S_GRID = np.linspace(0.0, 1.0, 2000)
INPUTS = [stats.norm(0, 1), stats.uniform(-1, 2), stats.beta(2, 3)]


def field(x):
    """A decaying, phase-shifted profile: not of finite rank in the inputs."""
    return np.exp(-(1 + 0.3 * x[0]) * S_GRID) * (1 + 0.2 * x[1] * np.sin(2 * np.pi * S_GRID + x[2]))


def test_compression_error_is_the_discarded_share_of_each_components_variance():
    rng = np.random.default_rng(0)
    Y = rng.standard_normal((40, 6)) @ rng.standard_normal((6, 50)) + 0.01 * rng.standard_normal(
        (40, 50)
    )
    Y[:, 7] = 3.0  # a constant component
    Z, V, ybar, err = compress_outputs(Y, 1e-2)
    resid = Y - ybar - Z @ V
    var = Y.var(axis=0)
    direct = np.where(var > 0, resid.var(axis=0) / np.where(var > 0, var, 1.0), 0.0)
    np.testing.assert_allclose(err, direct, atol=1e-12)
    assert err.max() <= 1e-2 and err[7] == 0.0
    # one component fewer would break the tolerance somewhere
    Z2, V2, _, err2 = compress_outputs(Y, 0.0)
    assert V.shape[0] < V2.shape[0]
    np.testing.assert_allclose(ybar + Z2 @ V2, Y, atol=1e-10)


def test_field_output_indices_agree_with_per_component_fits():
    pce = fit_pce(field, INPUTS, "lars", n_samples=300, seed=0)
    d = pce.diagnostics
    assert d["compressed"] and d["n_components"] < 20
    assert d["compression_error"].shape == S_GRID.shape
    assert np.all(d["corrected_loo_error"] >= d["compression_error"])
    idx = np.arange(1, len(S_GRID), 97)  # 21 components, one sparse fit each
    ref = fit_pce(lambda x: field(x)[idx], INPUTS, "lars", n_samples=300, seed=0, compress=False)
    assert not ref.diagnostics["compressed"]
    np.testing.assert_allclose(pce.first_order()[:, idx], ref.first_order(), atol=1e-3)
    np.testing.assert_allclose(pce.total()[:, idx], ref.total(), atol=1e-3)
    np.testing.assert_allclose(pce.mean[idx], ref.mean, rtol=1e-5)
    np.testing.assert_allclose(pce.variance[idx], ref.variance, rtol=1e-3)
    # and both against the model: a quadrature reference of the first-order indices
    quad = fit_pce(lambda x: field(x)[idx], INPUTS, "quadrature", order=8)
    np.testing.assert_allclose(pce.first_order()[:, idx], quad.first_order(), atol=1e-3)


def test_compress_arguments_are_checked():
    with pytest.raises(TypeError, match="compress"):
        fit_pce(field, INPUTS, "lars", n_samples=50, compress="yes")
    with pytest.raises(ValueError, match="compress_tol"):
        fit_pce(field, INPUTS, "lars", n_samples=50, compress_tol=2.0)
