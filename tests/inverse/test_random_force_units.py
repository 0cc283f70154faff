"""The random-force ECFM on a model built as a user builds one from the docs
(``docs/getting-started.md``: sine basis, terms, hat forces), in physical units.

A rod with conductivity ``eps0`` GPa, a reaction of 60 GPa (``U = 1e9``) and a load
``eps1 * 1e7``, seven sensors, data with a narrow source the model lacks (2 % noise):
the fit must not depend on the units (the same model with ``U = 1``); and where the load
term's reaction is weak (5 GPa) the likelihood runs along a ridge to infinity, where the
fit must end with a status, not a solver's exception.
"""

from __future__ import annotations

import numpy as np
import pytest

from ecfm_uq.inverse import FitStatus, SteadyProblem, fit
from ecfm_uq.spectral import SineBasis, hat_forces, load, mass, sensor_matrix, stiffness
from ecfm_uq.system import Coefficient, GalerkinSystem, LinearTerm, LoadTerm, solve_steady

BASIS = SineBasis(16)
SENSORS = np.linspace(0.1, 0.9, 7)


def rod(U, reaction, load_scale):
    def terms():
        return [
            LinearTerm(stiffness(BASIS), Coefficient.parameter(0, scale=U)),
            LinearTerm(mass(BASIS), Coefficient.constant(reaction * U)),
            LoadTerm.scaled(load(BASIS, np.ones_like), Coefficient.parameter(1, scale=load_scale)),
        ]

    system = GalerkinSystem(terms(), n_eps=2, Gamma=hat_forces(BASIS, SENSORS, half_width=0.15))
    M = sensor_matrix(BASIS, SENSORS)

    def src(x):
        return 1.5 * load_scale * np.exp(-0.5 * ((x - 0.62) / 0.05) ** 2)

    source = LoadTerm.scaled(load(BASIS, src), Coefficient.constant(1.0))
    truth_system = GalerkinSystem([*terms(), source], n_eps=2)
    clean = M @ solve_steady(truth_system, [3.0, 2.0]).Theta[:, 0]
    return system, M, clean, 0.02 * float(np.abs(clean).mean())


def data(clean, sigma, index):
    rng = np.random.default_rng(1)
    for _ in range(index + 1):
        v = clean + sigma * rng.standard_normal(clean.size)
    return v


def test_the_random_force_fit_does_not_depend_on_the_units():
    fits = {}
    for U in (1.0, 1e9):
        system, M, clean, sigma = rod(U, 60.0, U / 100)
        problem = SteadyProblem(system, M, data(clean, sigma, 0))
        fits[U] = fit(problem, [1.0, 1.0], formulation="ecfm-random", sigma=sigma)
    a, b = fits[1.0], fits[1e9]
    for res in (a, b):
        assert res.status is FitStatus.CONVERGED, res.message
        assert res.uncertainty.method == "marginal-likelihood-expected"
        assert res.verdict.consistent is False  # the missing source is found
    np.testing.assert_allclose(b.eps, a.eps, rtol=1e-6)
    np.testing.assert_allclose(b.uncertainty.stderr, a.uncertainty.stderr, rtol=1e-5)
    np.testing.assert_allclose(b.extra["tau"], 1e9 * a.extra["tau"], rtol=1e-5)  # forces in U
    assert b.verdict.p_value == pytest.approx(a.verdict.p_value, rel=1e-6)


@pytest.mark.parametrize("index", [28, 48])
def test_a_ridge_to_infinity_ends_with_a_status_not_brents_exception(index):
    """Data sets where the REML variance's root finder met a slope too rounded to converge
    (eps run to ~1e13 along the ridge; it raised RuntimeError from scipy's brentq)."""
    system, M, clean, sigma = rod(1e9, 5.0, 1e7)
    problem = SteadyProblem(system, M, data(clean, sigma, index))
    res = fit(problem, [1.0, 1.0], formulation="ecfm-random", sigma=sigma)
    assert isinstance(res.status, FitStatus)
    if res.status is not FitStatus.CONVERGED:
        assert "NOT converged" in res.message
    assert np.all(np.isfinite(res.eps))
