"""Fisher-KPP problem (Section 3.2): Kronecker quadratic form against dense tensors,
operators against closed forms and 2-D quadrature of the weak form, the true-state solve,
data generation and bad input."""

import numpy as np
import pytest

from ecfm_uq.problems.fisher_kpp import (
    DEFAULT_OMEGA,
    KroneckerTripleForm,
    build_kpp,
    make_data,
    relative_l1_error,
    sensor_grid,
    solve_true_state,
    source_relative_error,
    true_load,
    true_source,
    true_system,
)
from ecfm_uq.spectral import SineBasis, TensorBasis2D, composite_gauss
from ecfm_uq.system import DenseQuadraticForm


def _grid2d(n_panels=8, n=12):
    x, w = composite_gauss(np.arange(1, n_panels) / n_panels, n)
    X, Y = np.meshgrid(x, x, indexing="ij")
    return np.column_stack([X.ravel(), Y.ravel()]), np.outer(w, w).ravel()


def test_kronecker_form_matches_dense_2d_quadrature():
    # independent truth: A_ijk = int f_i f_j f_k on a 2-D Gauss grid, non-square basis
    basis = TensorBasis2D(SineBasis(3), SineBasis(4))
    form = KroneckerTripleForm.from_basis(basis)
    pts, w = _grid2d()
    f = basis.evaluate(pts)
    A = np.einsum("q,qi,qj,qk->ijk", w, f, f, f)
    assert np.max(np.abs(form.dense() - A)) < 1e-13
    dense = DenseQuadraticForm(A)
    rng = np.random.default_rng(3)
    X, Y = rng.standard_normal((2, basis.size, 3))
    assert np.allclose(form.apply(X, Y), dense.apply(X, Y), rtol=0, atol=1e-12)
    assert np.allclose(form.matrix(X[:, 0]), dense.matrix(X[:, 0]), rtol=0, atol=1e-12)


def test_kronecker_form_general_factors():
    # factors without symmetry in the last two indices exercise the A_ikj term
    rng = np.random.default_rng(4)
    ax, ay = rng.standard_normal((3, 3, 3)), rng.standard_normal((2, 2, 2))
    form = KroneckerTripleForm(ax, ay)
    A = np.einsum("ace,bdf->abcdef", ax, ay).reshape(6, 6, 6)
    dense = DenseQuadraticForm(A)
    X, Y = rng.standard_normal((2, 6, 4))
    assert np.allclose(form.apply(X, Y), dense.apply(X, Y), atol=1e-12)
    assert np.allclose(form.matrix(X[:, 1]), dense.matrix(X[:, 1]), atol=1e-12)


def test_1d_triple_products_closed_form():
    # int_0^1 sin(a pi x) sin(c pi x) sin(e pi x) dx = (1/4) sum over k = a+c-e, a-c+e,
    # -a+c+e (+) and a+c+e (-) of int sin(k pi x) = (1 - cos k pi)/(k pi)
    def s(k):
        return 0.0 if k == 0 else (1 - np.cos(k * np.pi)) / (k * np.pi)

    form = KroneckerTripleForm.from_basis(TensorBasis2D(SineBasis(6)))
    for a, c, e in [(1, 1, 1), (1, 2, 3), (2, 2, 5), (6, 5, 4), (3, 3, 3)]:
        exact = 0.25 * (s(a + c - e) + s(a - c + e) + s(-a + c + e) - s(a + c + e))
        assert form.ax[a - 1, c - 1, e - 1] == pytest.approx(exact, abs=1e-14)


def test_residual_matches_weak_form_by_2d_quadrature():
    # R_i = int 1/2 grad f_i . grad w - f_i w + f_i w^2 - f_i b  (weak form of Eq. kpp_param)
    p = build_kpp(n_state=4, n_source=2, sensors=sensor_grid(3))
    rng = np.random.default_rng(5)
    theta, eps = rng.standard_normal(p.basis.size), rng.standard_normal(p.n_eps)
    pts, w = _grid2d()
    f = p.basis.evaluate(pts)
    fx = p.basis.evaluate(pts, derivative=(1, 0))
    fy = p.basis.evaluate(pts, derivative=(0, 1))
    u, ux, uy = f @ theta, fx @ theta, fy @ theta
    b = p.source_basis.evaluate(pts) @ eps
    R = (0.5 * (fx.T @ (w * ux) + fy.T @ (w * uy))) - f.T @ (w * u) + f.T @ (w * u**2)
    R -= f.T @ (w * b)
    got = p.system.residual(theta[:, None], eps).ravel()
    assert np.max(np.abs(got - R)) < 1e-12 * max(1.0, np.max(np.abs(R)))


def test_linear_operator_closed_form():
    # sines: M = I/4, K diagonal pi^2 (a^2 + b^2)/4 in 2-D
    p = build_kpp(n_state=5, n_source=2, sensors=sensor_grid(3))
    a, b = np.meshgrid(np.arange(1, 6), np.arange(1, 6), indexing="ij")
    diag = 0.5 * np.pi**2 * (a**2 + b**2).ravel() / 4 - 0.25
    # off-diagonal entries are quadrature round-off of exact zeros
    assert np.allclose(p.L, np.diag(diag), rtol=0, atol=1e-14 * diag.max())


def test_true_load_closed_form():
    basis = TensorBasis2D(SineBasis(7))
    k = np.pi * np.arange(1, 8)
    g = (np.cos(0.25 * k) - np.cos(0.75 * k)) / k
    assert np.allclose(true_load(basis), 100.0 * np.kron(g, g), rtol=0, atol=1e-12)


def test_rbf_force_columns_integrate_to_about_one():
    # Gamma_ij = int f_i Gamma_j; projecting back gives sum_i c_i f_i ~ Gamma_j, whose
    # integral over the square is ~1 for a sensor far from the boundary
    p = build_kpp(n_state=24, n_source=2, sensors=np.array([[0.5, 0.5]]))
    coef = 4.0 * p.Gamma[:, 0]  # M^-1 = 4 I for the 2-D sine basis
    k = np.arange(1, 25)
    mean_sine = (1 - np.cos(k * np.pi)) / (k * np.pi)
    assert np.kron(mean_sine, mean_sine) @ coef == pytest.approx(1.0, abs=1e-3)
    assert p.omega == DEFAULT_OMEGA == 128.0


def test_jacobian_taylor_test():
    p = build_kpp(n_state=4, n_source=2, sensors=sensor_grid(3))
    rng = np.random.default_rng(6)
    th, d = rng.standard_normal((2, p.basis.size, 1))
    eps = rng.standard_normal(p.n_eps)
    R0 = p.system.residual(th, eps).ravel()
    J = p.system.jacobian(th, eps)
    errs = []
    for h in (1e-2, 5e-3, 2.5e-3):
        Rh = p.system.residual(th + h * d, eps).ravel()
        errs.append(np.linalg.norm(Rh - R0 - h * J @ d.ravel()))
    # quadratic model: the first-order remainder is exactly O(h^2)
    assert errs[0] / errs[1] == pytest.approx(4.0, rel=1e-4)
    assert errs[1] / errs[2] == pytest.approx(4.0, rel=1e-4)


def test_true_state_newton_converges_and_is_symmetric():
    p = build_kpp()
    theta, steps, nit = solve_true_state(p)
    assert steps == 1 and nit < 15  # Newton from zero suffices at s = 100
    # residual of the true problem (Eq. kpp on the state basis) is at round-off
    R = true_system(p).residual(theta[:, None], [1.0])
    assert np.linalg.norm(R) < 1e-10
    # and it is not the trivial state: s = 100 drives u to about 6 at the centre
    assert 5.0 < p.basis.evaluate_grid(theta, [0.5], [0.5])[0, 0] < 8.0
    T = theta.reshape(10, 10)
    assert np.allclose(T, T.T, atol=1e-10)  # symmetric source, symmetric solution
    # even modes vanish (source symmetric about x = 1/2)
    assert np.max(np.abs(T[1::2, :])) < 1e-10


def test_make_data_is_seeded_and_noisy():
    p = build_kpp(n_state=6, n_source=2)
    d1, d2 = make_data(p, 0.05, seed=3), make_data(p, 0.05, seed=3)
    assert np.array_equal(d1.v, d2.v)
    d3 = make_data(p, 0.05, seed=4)
    assert not np.array_equal(d1.v, d3.v)
    assert np.allclose(d1.v - d1.noise, p.M_obs @ d1.theta_true)
    assert 0.04 < d1.noise.std() < 0.06  # 225 draws of N(0, 0.05^2)


def test_error_metrics():
    p = build_kpp(n_state=6, n_source=2)
    theta = np.random.default_rng(0).standard_normal(p.basis.size)
    assert relative_l1_error(p, theta, theta) == 0.0
    assert relative_l1_error(p, theta, 1.1 * theta) == pytest.approx(0.1, rel=1e-12)
    assert relative_l1_error(p, theta, np.zeros_like(theta)) == pytest.approx(1.0)
    # b = 0 gives relative error 1; a source exactly s would give 0 (not representable)
    assert source_relative_error(p, np.zeros(p.n_eps)) == pytest.approx(1.0)
    pts = np.array([[0.5, 0.5], [0.1, 0.5], [0.25, 0.75]])
    assert np.array_equal(true_source(pts), [100.0, 0.0, 100.0])


def test_40x40_builds_in_factored_form():
    # the Newton solve at N = 1600 (time, peak memory) is measured in benchmarks/kpp.py
    p = build_kpp(n_state=40, n_source=4)
    assert p.system.N == 1600 and p.A.ax.shape == (40, 40, 40)
    theta = np.random.default_rng(8).standard_normal(1600)
    # symmetric A: A:theta theta = (1/2) S(theta) theta
    q = p.A.apply(theta[:, None], theta[:, None])[:, 0]
    assert np.allclose(q, 0.5 * p.A.matrix(theta) @ theta, rtol=1e-12, atol=1e-12)


def test_bad_input():
    with pytest.raises(ValueError, match="sensors"):
        build_kpp(sensors=np.array([[0.5, 1.2]]))
    with pytest.raises(ValueError, match="sensors"):
        build_kpp(sensors=np.array([[0.0, 0.5]]))
    with pytest.raises(ValueError, match="sensors"):
        build_kpp(sensors=np.array([[np.nan, 0.5]]))
    with pytest.raises(ValueError, match="omega"):
        build_kpp(omega=-1.0)
    with pytest.raises(ValueError, match="n_state"):
        build_kpp(n_state=0)
    p = build_kpp(n_state=4, n_source=2, sensors=sensor_grid(3))
    with pytest.raises(ValueError, match="sigma"):
        make_data(p, sigma=0.0)
    with pytest.raises(ValueError, match="sigma"):
        make_data(p, sigma=-0.05)
    with pytest.raises(ValueError, match="`ax`"):
        KroneckerTripleForm(np.ones((2, 2, 3)), np.ones((2, 2, 2)))
    with pytest.raises(TypeError, match="TensorBasis2D"):
        KroneckerTripleForm.from_basis(SineBasis(3))


def test_relative_error_refuses_non_finite_or_misshaped_coefficients():
    # a failed fit handing over NaN coefficients must not produce a NaN error silently
    p = build_kpp(n_state=4, n_source=2, sensors=sensor_grid(3))
    good = np.ones(p.basis.size)
    bad = good.copy()
    bad[3] = np.nan
    with pytest.raises(ValueError, match="theta"):
        relative_l1_error(p, good, bad)
    with pytest.raises(ValueError, match="theta_ref"):
        relative_l1_error(p, bad, good)
    with pytest.raises(ValueError, match="theta"):
        relative_l1_error(p, good, np.ones(p.basis.size + 1))
