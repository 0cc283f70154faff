"""The random-force ECFM's per-point shortcuts give the same bits as what they replace.

The Cholesky factor and solves by their LAPACK calls directly (against
``scipy.linalg.cho_factor``/``cho_solve``, and their errors), the profiled expected
information the fit reports (against a fresh computation), and the REML
derivative from linearize's SVD (against one that computes its own).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy import linalg

from ecfm_uq.inverse import SteadyProblem, fit
from ecfm_uq.inverse.formulations import random_force_gradient as rg
from ecfm_uq.inverse.formulations.random_force_scoring import profiled_information
from ecfm_uq.inverse.formulations.random_forces import RandomForceModel
from ecfm_uq.problems.reaction import ReactionRod
from ecfm_uq.system.solve.factors import cho_factor, cho_solve


def spd(n, seed=0):
    X = np.random.default_rng(seed).standard_normal((n, n))
    return X @ X.T + 0.1 * np.eye(n)


@pytest.mark.parametrize("shape", [(6,), (6, 3)])
def test_cholesky_calls_give_scipys_bits(shape):
    S = spd(6)
    b = np.random.default_rng(1).standard_normal(shape)
    c = cho_factor(S)
    ref = linalg.cho_factor(S)
    np.testing.assert_array_equal(c, ref[0])
    np.testing.assert_array_equal(cho_solve(c, b), linalg.cho_solve(ref, b))
    np.testing.assert_allclose(S @ cho_solve(c, b), b, rtol=1e-10, atol=1e-12)


def test_cholesky_calls_refuse_what_scipy_refuses():
    S = spd(4)
    bad = S.copy()
    bad[0, 1] = np.nan
    with pytest.raises(ValueError, match="infs or NaNs"):
        cho_factor(bad)
    with pytest.raises(np.linalg.LinAlgError, match="not positive definite"):
        cho_factor(-S)
    with pytest.raises(ValueError, match="infs or NaNs"):
        cho_solve(cho_factor(S), np.array([1.0, np.inf, 0.0, 0.0]))


def rod_model():
    rod = ReactionRod(6)
    truth = np.array([1.5, 20.0])
    clean = rod.data(truth)
    sigma = 0.02 * float(np.abs(clean).mean())
    v = rod.data(truth, 16.0, 0.62) + sigma * np.random.default_rng(0).standard_normal(6)
    return RandomForceModel(SteadyProblem(rod.system, rod.M_obs, v), sigma), truth


def test_the_expected_information_reported_is_a_fresh_computations():
    """The fit's delta method takes the information Fisher scoring computed at its last
    point (carried on the search's result, not recomputed): it is the inverse of
    ``profiled_information`` of a fresh model at the estimate, to rounding."""
    model, truth = rod_model()
    res = fit(model.problem, truth, formulation="ecfm-random", sigma=model.sigma)
    assert res.uncertainty.method == "marginal-likelihood-expected"
    fresh = RandomForceModel(model.problem, model.sigma)
    t = float(fresh.profiled(res.eps)[1][0])
    assert t > 0.0
    F = profiled_information(fresh.linearization(res.eps, second=True), model.sigma, t)
    np.testing.assert_allclose(res.uncertainty.cov, np.linalg.inv(F), rtol=1e-10, atol=0)
    se = np.sqrt(np.diag(res.uncertainty.cov))
    np.testing.assert_array_equal(res.uncertainty.stderr, se)
    np.testing.assert_allclose(
        res.uncertainty.intervals,
        res.eps[:, None] + 1.959963984540054 * np.outer(se, [-1, 1]),
        rtol=1e-14,
    )


def test_the_reml_derivative_from_linearizes_svd_is_its_own():
    model, truth = rod_model()
    lin = model.linearization(truth, second=True)
    assert lin.svd is not None
    s = float(model.profiled(truth)[1][0]) * model.a0**2 / model.sigma**2
    ds = rg._reml_derivative(lin, lin.dA, lin.dJ, model.sigma, s, model.a0)
    # the SVD of J's unit columns computed here, by numpy, with the rank by lstsq's rule
    norms = np.linalg.norm(lin.J, axis=0)
    live = norms > 0
    U, sv, Vt = np.linalg.svd(lin.J[:, live] / norms[live], full_matrices=True)
    rank = int(np.sum(sv > max(lin.J.shape[0], int(live.sum())) * np.finfo(float).eps * sv[0]))
    mine = replace(lin, svd=(norms, U, sv, Vt, rank))
    own = rg._reml_derivative(mine, lin.dA, lin.dJ, model.sigma, s, model.a0)
    np.testing.assert_array_equal(ds, own)
    assert np.all(np.isfinite(ds)) and np.any(ds != 0.0)
