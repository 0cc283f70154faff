"""The Burgers model of paper Section 3.1 against closed forms and an independent
hand-written time stepper."""

import numpy as np
import pytest
import scipy.optimize as sopt

from ecfm_uq.errors import ConvergenceError
from ecfm_uq.problems.burgers import BurgersModel, ConvectionForm, initial_condition
from ecfm_uq.spectral import SineBasis, SinusoidBasis, composite_gauss


@pytest.fixture(scope="module")
def small():
    return BurgersModel(n_modes=12, n_steps=20, T=1.0)


def test_operators_closed_form(small):
    N = small.n_modes
    i = np.arange(1, N + 1)
    np.testing.assert_allclose(small.M, np.eye(N) / 2, atol=1e-13)
    np.testing.assert_allclose(small.K, np.diag((i * np.pi) ** 2 / 2), atol=1e-10)
    # F(t) = sin(2 pi t) int sin(2 pi x) f_i = sin(2 pi t) delta_{i2} / 2
    np.testing.assert_allclose(small.F0, np.eye(N)[1] / 2, atol=1e-13)
    # sensors M_ij = f_j(x_i)
    np.testing.assert_allclose(small.M_obs, np.sin(np.outer(small.sensors, i * np.pi)), atol=1e-14)
    # hat: int sin(k x) max(0, 1 - |x - c|/a) dx = sin(k c) 2 (1 - cos(k a)) / (k^2 a)
    a, k = small.hat_half_width, i * np.pi
    want = np.sin(np.outer(k, small.sensors)) * (2 * (1 - np.cos(k * a)) / (k**2 * a))[:, None]
    np.testing.assert_allclose(small.Gamma, want, atol=1e-13)


def test_default_hat_width_is_sensor_spacing():
    assert BurgersModel(n_modes=4, n_steps=1).hat_half_width == pytest.approx(0.2)
    assert BurgersModel(n_modes=4, n_steps=1, sensors=(0.25, 0.5, 0.75)).hat_half_width == 0.25


def test_initial_state_projection_vs_paper_formula(small):
    # u0 = sin(2 pi x) = f_2: the L2 projection is e_2; the printed formula gives e_2 / 2
    e2 = np.eye(small.n_modes)[1]
    np.testing.assert_allclose(small.theta0, e2, atol=1e-13)
    paper = BurgersModel(n_modes=12, n_steps=20, initial_state="paper")
    np.testing.assert_allclose(paper.theta0, e2 / 2, atol=1e-13)
    x = np.linspace(0, 1, 9)
    np.testing.assert_allclose(small.field(small.Theta0, x), initial_condition(x), atol=1e-13)


def test_convection_index_convention_closed_form(small):
    # w = a sin(pi x): w w_x = a^2 pi sin(2 pi x) / 2, so int f_i w w_x = a^2 pi / 4 delta_{i2}
    a = 0.7
    th = a * np.eye(small.n_modes)[0]
    q = small.system.terms[0].form.apply(th[:, None], th[:, None])[:, 0]
    np.testing.assert_allclose(q, a**2 * np.pi / 4 * np.eye(small.n_modes)[1], atol=1e-13)
    # the dense triple() tensor A_ijk = int f_i f_j f_k' gives the same contraction
    np.testing.assert_allclose(np.einsum("ijk,j,k->i", small.A, th, th), q, atol=1e-12)


def test_convection_form_matches_dense_tensor_and_weak_form(small):
    rng = np.random.default_rng(0)
    form = ConvectionForm(small.basis)
    X = rng.standard_normal((small.n_modes, 3))
    Y = rng.standard_normal((small.n_modes, 3))
    np.testing.assert_allclose(
        form.apply(X, Y), np.einsum("ijk,jm,km->im", small.A, X, Y), rtol=1e-12, atol=1e-10
    )
    Asym = small.A + small.A.transpose(0, 2, 1)
    np.testing.assert_allclose(form.matrix(X[:, 0]), Asym @ X[:, 0], rtol=1e-12, atol=1e-10)
    # A_ijk theta_j theta_k = int f_i w w_x by a fine composite Gauss rule
    xq, wq = composite_gauss((), 200)
    th = X[:, 0]
    w = small.basis.evaluate(xq) @ th
    wx = small.basis.evaluate(xq, 1) @ th
    ref = small.basis.evaluate(xq).T @ (wq * w * wx)
    np.testing.assert_allclose(form.apply(th[:, None], th[:, None])[:, 0], ref, atol=1e-11)
    # convection conserves energy: theta . A:(theta theta) = int w^2 w_x = 0
    assert abs(th @ form.apply(th[:, None], th[:, None])[:, 0]) < 1e-11


def test_convection_form_bad_input():
    with pytest.raises(ValueError, match="n_points"):
        ConvectionForm(SineBasis(10), n_points=10)
    with pytest.raises(TypeError, match="SineBasis"):
        ConvectionForm(SinusoidBasis([1.0, 2.0]))


def test_march_matches_hand_written_backward_euler(small):
    """Eq. backward_euler solved step by step with scipy's root finder on dense operators."""
    eps = np.array([1.6, 0.9])
    n = 5
    traj = BurgersModel(n_modes=12, n_steps=n, T=0.25).solve(eps, strict=True)
    dt = 0.25 / n
    nu = 10 ** -eps[0]
    A, M, K, F0 = small.A, small.M, small.K, small.F0
    th = small.theta0.copy()
    for s in range(1, n + 1):
        Ft = eps[1] * np.sin(2 * np.pi * s * dt) * F0
        prev = th

        def R(z, prev=prev, Ft=Ft):
            return M @ (z - prev) / dt + np.einsum("ijk,j,k->i", A, z, z) + nu * K @ z - Ft

        sol = sopt.root(R, prev, tol=1e-13)
        assert np.linalg.norm(R(sol.x)) < 1e-11
        th = sol.x
        np.testing.assert_allclose(traj.Theta[s, :, 0], th, atol=1e-10)


def test_true_data_shape_and_first_row(small):
    V = small.true_data()
    assert V.shape == (small.n_steps + 1, small.sensors.size)
    np.testing.assert_allclose(V[0], initial_condition(small.sensors), atol=1e-13)
    assert np.all(np.isfinite(V))


def test_ecfm_solve_meets_data_and_has_zero_force_at_truth(small):
    V = small.true_data((1.75, 1.0))
    tr = small.solve((1.75, 1.0), data=V)
    assert tr.success
    np.testing.assert_allclose(small.measure(tr), V, atol=1e-10)
    assert np.abs(tr.lam).max() < 1e-9
    tr = small.solve((1.5, 0.7), data=V)  # wrong parameters: the data still hold, forces work
    np.testing.assert_allclose(small.measure(tr)[1:], V[1:], atol=1e-10)
    assert np.abs(tr.lam).max() > 1e-2


def test_newton_failure_names_step_and_residual():
    # nearly inviscid (nu = 1e-8) with a huge source and 8 steps over [0, 2]: no solution
    # is found at step 5
    model = BurgersModel(n_modes=20, n_steps=8, T=2.0)
    tr = model.solve((8.0, 1e3))
    assert not tr.success
    assert tr.failed_step == 5
    assert "step 5" in tr.message and "||R||=" in tr.message
    assert tr.Theta.shape[0] == 5  # only converged states are returned
    with pytest.raises(ConvergenceError, match=r"step 5 .*\|\|R\|\|="):
        model.solve((8.0, 1e3), strict=True)


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"hat_half_width": -0.1}, "hat_half_width"),
        ({"sensors": (0.2, 1.2)}, "sensors"),
        ({"sensors": (0.2, np.nan)}, "sensors"),
        ({"sensors": (0.2, 0.2)}, "sensors"),
        ({"n_modes": 0}, "n_modes"),
        ({"T": -1.0}, "T"),
        ({"newton_tol": 0.0}, "newton_tol"),
        ({"initial_state": "exact"}, "initial_state"),
        ({"viscosity_spread": -1.0}, "viscosity_spread"),
    ],
)
def test_bad_model_input(kw, match):
    with pytest.raises(ValueError, match=match):
        BurgersModel(n_modes=kw.pop("n_modes", 4), n_steps=2, **kw)


def test_bad_solve_input(small):
    with pytest.raises(ValueError, match="eps"):
        small.solve((1.0, 2.0, 3.0))
    with pytest.raises(ValueError, match="v"):
        small.solve((1.75, 1.0), data=np.zeros((3, 4)))
    bad = np.zeros((small.n_steps + 1, 4))
    bad[2, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        small.solve((1.75, 1.0), data=bad)
