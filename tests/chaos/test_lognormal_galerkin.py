"""Stochastic Galerkin with Hermite germs: 1-D diffusion with a lognormal coefficient.

-(a u')' = 1 on (0, 1), u(0) = u(1) = 0, a(x, xi) = exp(sum_k sqrt(l_k) phi_k(x) xi_k) with
two independent standard normal germs (a truncated Karhunen-Loeve Gaussian field). The
coefficient is expanded exactly in Hermite chaos of order 2p (lognormal_coefficients) and
enters through coupling_tensor, one LinearTerm per coefficient term, through the
unchanged system API. References: tensor Gauss-Hermite collocation (24^2 solves) and
Monte Carlo.

This is the chaos layer's part of issue 22 item 4; the scikit-fem problem with a KL of a
2-D Gaussian field belongs to problems/ (see the report).
"""

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ecfm_uq.chaos import ChaosBasis, coupling_tensor, lognormal_coefficients
from ecfm_uq.system import GalerkinSystem, LinearTerm, LoadTerm, solve_steady

N = 31
H = 1.0 / (N + 1)
XC = (np.arange(N + 1) + 0.5) * H  # cell midpoints
LAM = 0.25 * np.array([1.0, 0.3])  # field variance 0.25 in the first mode
B = np.column_stack([np.sqrt(LAM[k]) * np.sin((k + 1) * np.pi * XC) for k in range(2)])
F = np.full(N, H)


def stiffness(a):
    """P1 stiffness with a per-cell coefficient ``a`` (N + 1,)."""
    a = a / H
    return sp.diags([-a[1:-1], a[:-1] + a[1:], -a[1:-1]], [-1, 0, 1], format="csc")


def solve(xi):
    return spla.spsolve(stiffness(np.exp(B @ xi)), F)


def galerkin(p):
    basis = ChaosBasis(p, 2, germ="hermite")
    coef = ChaosBasis(2 * p, 2, germ="hermite")  # higher terms do not couple order-p terms
    A = lognormal_coefficients(coef, B)  # (N + 1, Pa)
    T = coupling_tensor(coef, basis)  # (Pa, P, P)
    terms = [LinearTerm(stiffness(A[:, a]).tocsr(), G=T[a]) for a in range(coef.size)]
    terms.append(LoadTerm.constant(F))
    sol = solve_steady(GalerkinSystem(terms, 1, basis=basis), np.zeros(1))
    assert sol.success
    return sol.Theta[:, 0], (sol.Theta[:, 1:] ** 2).sum(axis=1)


@pytest.fixture(scope="module")
def collocation():
    x, w = ChaosBasis(0, 2, germ="hermite").quadrature(24)
    U = np.array([solve(xi) for xi in x])
    mean = w @ U
    return mean, w @ (U - mean) ** 2


def test_truncation_error_table_by_order(collocation):
    mref, vref = collocation
    err_m, err_v = [], []
    for p in range(1, 6):
        m, v = galerkin(p)
        err_m.append(np.abs(m - mref).max() / np.abs(mref).max())
        err_v.append(np.abs(v - vref).max() / np.abs(vref).max())
    err_m, err_v = np.array(err_m), np.array(err_v)
    # spectral convergence: each order gains at least a factor 5 in both
    assert np.all(err_m[1:] < err_m[:-1] / 5) and np.all(err_v[1:] < err_v[:-1] / 5)
    # the order at which the truncation error falls below 1e-3
    assert int(np.argmax(err_m < 1e-3)) + 1 == 2
    assert int(np.argmax(err_v < 1e-3)) + 1 == 4
    assert err_v[-1] < 1e-4


def test_galerkin_against_monte_carlo_within_its_standard_errors():
    m, v = galerkin(4)
    rng = np.random.default_rng(0)
    U = np.array([solve(rng.standard_normal(2)) for _ in range(3000)])
    n = len(U)
    se_m = U.std(axis=0, ddof=1) / np.sqrt(n)
    d = U - U.mean(axis=0)
    se_v = np.sqrt(np.maximum(np.mean(d**4, axis=0) - U.var(axis=0, ddof=1) ** 2, 0) / n)
    assert np.all(np.abs(U.mean(axis=0) - m) < 4 * se_m)
    assert np.all(np.abs(U.var(axis=0, ddof=1) - v) < 4 * se_v)
