"""Heat-conduction problems of paper Section 4: discretizations against closed-form
solutions, the mapped operators against direct assembly on the physical domain, analytic
parameter derivatives against central differences (Taylor tests), and bad input."""

import numpy as np
import pytest

from ecfm_uq.problems.heat import (
    boundary_closed_form,
    boundary_problem,
    gaussian_source,
    interval_closed_form,
    interval_problem,
    rectangle_problem,
    uniform_sensors,
)
from ecfm_uq.spectral import BeamBasis, gram_vector, load, stiffness


def _gauss(a, b, n=200):
    t, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (b - a) * t + 0.5 * (b + a), 0.5 * (b - a) * w


# --------------------------------------------------------------------------------------
# closed forms (independent truth)
# --------------------------------------------------------------------------------------
def test_boundary_case_converges_to_the_closed_form_solution():
    # w'' + s = 0, w(0) = e1, w'(1) = e2  ->  w = e1 + e2 x + s (x - x^2/2)
    e1, e2, s = 0.7, -1.3, 2.0
    x = np.linspace(0.0, 1.0, 401)
    exact = e1 + e2 * x + s * (x - 0.5 * x**2)
    interior, everywhere = [], []
    for n in (10, 20, 40):
        p = boundary_problem(n_basis=n, sensors=2, s=s)
        err = np.abs(p.field(p.solve([e1, e2]), x) - exact)
        interior.append(err[x <= 0.9].max())
        everywhere.append(err.max())
    # beam modes have f'(1) = 0 while w'(1) = e2 + ... != 0: the Neumann end converges like
    # 1/N in the max norm, the interior like 1/N^2 (see docs/heat.md)
    assert interior[-1] < 3e-4 and everywhere[-1] < 4e-3
    assert interior[0] / interior[1] > 2.5 and interior[1] / interior[2] > 3.0
    assert everywhere[0] / everywhere[1] > 1.8 and everywhere[1] / everywhere[2] > 1.8
    # the Dirichlet value is exact through the lift
    p = boundary_problem(n_basis=10, sensors=2, s=s)
    assert p.field(p.solve([e1, e2]), np.array([0.0]))[0] == pytest.approx(e1, abs=1e-14)


def test_boundary_closed_form_helper_matches_the_bvp():
    x = np.linspace(0, 1, 11)
    w = boundary_closed_form(x, [0.3, 2.0], s=4.0)
    assert w[0] == pytest.approx(0.3)
    h = 1e-5
    slope = (
        boundary_closed_form(np.array([1.0]), [0.3, 2.0], 4.0)[0]
        - boundary_closed_form(np.array([1.0 - h]), [0.3, 2.0], 4.0)[0]
    ) / h
    assert slope == pytest.approx(2.0, abs=1e-3)
    np.testing.assert_allclose(np.diff(w, 2) / 0.1**2, -4.0, rtol=1e-10)


def test_interval_case_converges_to_the_closed_form_solution():
    # w'' + 1 + x = 0 on [0, L], w(0) = w(L) = 0
    L = 1.7
    xi = np.linspace(0.0, 1.0, 301)
    X = L * xi
    exact = -(X**2) / 2 - X**3 / 6 + (L / 2 + L**2 / 6) * X
    errs = []
    for n in (10, 20, 40):
        p = interval_problem(n_basis=n, sensors=2)
        errs.append(np.abs(p.field(p.solve([L]), xi) - exact).max())
    assert errs[-1] < 2e-4
    # sine coefficients of a function with nonzero w'' at the ends decay like k^-3
    assert errs[0] / errs[1] > 3.0 and errs[1] / errs[2] > 3.0
    np.testing.assert_allclose(interval_closed_form(X, L), exact, rtol=1e-14)


def test_rectangle_case_converges_to_a_manufactured_solution():
    # w = x (a - x) y (b - y) solves lap w + s = 0 with s = 2 y (b - y) + 2 x (a - x)
    a, b = 1.5, 0.8

    def s(x, y):
        return 2 * y * (b - y) + 2 * x * (a - x)

    def grad_s(x, y):
        return 2 * (a - 2 * x), 2 * (b - 2 * y)

    g = np.linspace(0, 1, 41)
    XI, ETA = np.meshgrid(g, g, indexing="ij")
    pts = np.column_stack([XI.ravel(), ETA.ravel()])
    X, Y = a * pts[:, 0], b * pts[:, 1]
    exact = X * (a - X) * Y * (b - Y)
    errs = []
    for n in (8, 16):
        p = rectangle_problem(n_basis=n, sensors=2, s=s, grad_s=grad_s)
        errs.append(np.abs(p.field(p.solve([a, b]), pts) - exact).max())
    assert errs[-1] < 1e-3 * exact.max()
    assert errs[0] / errs[1] > 4.0


# --------------------------------------------------------------------------------------
# the paper's weak forms, assembled independently
# --------------------------------------------------------------------------------------
def test_boundary_system_is_the_papers_weak_form_after_eliminating_the_lift():
    n, s, e1, e2 = 12, 3.0, 0.4, -0.9
    p = boundary_problem(n_basis=n, sensors=3, s=s)
    basis = BeamBasis(n)
    f1 = basis.evaluate(np.array([1.0]))[0]
    # K theta = int s f + h f(1) - int g' f',  g = e1 (1 - x)  (g' = -e1)
    rhs = load(basis, lambda x: np.full_like(x, s)) + e2 * f1
    rhs -= gram_vector(basis, lambda x: np.full_like(x, -e1), derivative=1)
    theta = np.linalg.solve(stiffness(basis), rhs)
    z = p.solve([e1, e2])
    np.testing.assert_allclose(z[:n], theta, rtol=1e-11, atol=1e-13)
    assert z[n] == pytest.approx(e1)
    # the sensors see the lifted temperature
    x_c = p.sensors
    w_c = basis.evaluate(x_c) @ theta + e1 * (1 - x_c)
    np.testing.assert_allclose(p.measure([e1, e2]), w_c, rtol=1e-12)


def test_interval_operators_equal_direct_assembly_on_the_physical_domain():
    n, L = 8, 1.3
    s = lambda x: np.exp(0.5 * x) + x**2
    p = interval_problem(n_basis=n, sensors=2, s=s, grad_s=lambda x: 0.5 * np.exp(0.5 * x) + 2 * x)
    K, F = p.operators([L])
    x, w = _gauss(0.0, L)
    k = np.pi * np.arange(1, n + 1) / L  # f_i(x) = sin(i pi x / L)
    f = np.sin(np.outer(x, k))
    df = k * np.cos(np.outer(x, k))
    np.testing.assert_allclose(K, (df * w[:, None]).T @ df, rtol=1e-11, atol=1e-11)
    np.testing.assert_allclose(F, f.T @ (w * s(x)), rtol=1e-11, atol=1e-12)


def test_rectangle_operators_equal_direct_assembly_on_the_physical_domain():
    n, a, b = 4, 1.4, 0.7
    s = lambda x, y: np.cos(x) * (1 + y**2)
    gs = lambda x, y: (-np.sin(x) * (1 + y**2), 2 * y * np.cos(x))
    p = rectangle_problem(n_basis=n, sensors=2, s=s, grad_s=gs)
    K, F = p.operators([a, b])
    x, wx = _gauss(0.0, a, 80)
    y, wy = _gauss(0.0, b, 80)
    kx, ky = np.pi * np.arange(1, n + 1) / a, np.pi * np.arange(1, n + 1) / b
    fx, dfx = np.sin(np.outer(x, kx)), kx * np.cos(np.outer(x, kx))
    fy, dfy = np.sin(np.outer(y, ky)), ky * np.cos(np.outer(y, ky))
    Kx, Mx = (dfx * wx[:, None]).T @ dfx, (fx * wx[:, None]).T @ fx
    Ky, My = (dfy * wy[:, None]).T @ dfy, (fy * wy[:, None]).T @ fy
    np.testing.assert_allclose(K, np.kron(Kx, My) + np.kron(Mx, Ky), rtol=1e-10, atol=1e-12)
    S = s(x[:, None], y[None, :]) * np.outer(wx, wy)
    np.testing.assert_allclose(F, (fx.T @ S @ fy).ravel(), rtol=1e-10, atol=1e-12)


# --------------------------------------------------------------------------------------
# Taylor tests of dK/deps and dF/deps
# --------------------------------------------------------------------------------------
def _problems():
    s1 = lambda x: np.exp(0.5 * x) + np.sin(3 * x)
    ds1 = lambda x: 0.5 * np.exp(0.5 * x) + 3 * np.cos(3 * x)
    s2 = lambda x, y: np.exp(0.3 * x - 0.2 * y) + x * y
    ds2 = lambda x, y: (0.3 * np.exp(0.3 * x - 0.2 * y) + y, -0.2 * np.exp(0.3 * x - 0.2 * y) + x)
    return {
        "boundary": (boundary_problem(10, 3, s=2.0), np.array([0.8, -0.4])),
        "interval": (interval_problem(10, 3, s=s1, grad_s=ds1), np.array([1.3])),
        "rectangle": (rectangle_problem(6, 2, s=s2, grad_s=ds2), np.array([1.4, 0.9])),
    }


@pytest.mark.parametrize("name", ["boundary", "interval", "rectangle"])
def test_parameter_derivatives_against_central_differences(name):
    problem, eps = _problems()[name]
    system = problem.system
    rng = np.random.default_rng(0)
    theta = rng.normal(size=system.shape)
    zero = system.zeros()
    d = rng.normal(size=eps.size)
    d /= np.linalg.norm(d)
    # analytic: d(K theta)/deps . d and dF/deps . d, read off the system's eps-Jacobian
    dR = system.eps_jacobian(theta, eps) @ d
    dF = -system.eps_jacobian(zero, eps) @ d
    dKt = dR + dF

    def parts(e):
        K, F = problem.operators(e)
        return K @ theta[:, 0], F

    errors_K, errors_F = [], []
    hs = [0.1, 0.05, 0.025]
    for h in hs:
        Kp, Fp = parts(eps + h * d)
        Km, Fm = parts(eps - h * d)
        errors_K.append(np.linalg.norm((Kp - Km) / (2 * h) - dKt))
        errors_F.append(np.linalg.norm((Fp - Fm) / (2 * h) - dF))
    scale = max(np.linalg.norm(dKt), np.linalg.norm(dF))
    for errors in (errors_K, errors_F):
        if errors[0] < 1e-10 * scale:  # affine in eps: differences are exact
            assert max(errors) < 1e-9 * scale
        else:  # second order: halving h quarters the error
            rates = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
            np.testing.assert_allclose(rates, 2.0, atol=0.15)


def test_rectangle_stiffness_is_symmetric_positive_definite():
    problem, eps = _problems()["rectangle"]
    K, _ = problem.operators(eps)
    np.testing.assert_allclose(K, K.T, atol=1e-12)
    assert np.linalg.eigvalsh(K).min() > 0


def test_force_shapes_are_fixed_in_reference_coordinates():
    # Gamma does not depend on eps, so the physical density scales with 1/(a b)
    problem, eps = _problems()["rectangle"]
    lam = np.arange(1.0, problem.centers.shape[0] + 1)
    pts = problem.centers[:1]
    ref = problem.force_density(lam, pts)
    phys = problem.force_density(lam, pts, eps)
    np.testing.assert_allclose(phys, ref / np.prod(eps))


def test_uniform_sensors_and_sources():
    np.testing.assert_allclose(uniform_sensors(3), [0.25, 0.5, 0.75])
    assert uniform_sensors(2, dim=2).shape == (4, 2)
    s, ds = gaussian_source(0.3, 0.1, 2.0)
    assert s(np.array([0.3]))[0] == pytest.approx(2.0)
    h = 1e-6
    assert ds(np.array([0.35]))[0] == pytest.approx((s(0.35 + h) - s(0.35 - h)) / (2 * h), rel=1e-6)


# --------------------------------------------------------------------------------------
# bad input
# --------------------------------------------------------------------------------------
def test_non_positive_domain_size_is_rejected():
    with pytest.raises(ValueError, match="positive"):
        interval_problem(8, 2).measure([0.0])
    with pytest.raises(ValueError, match="positive"):
        interval_problem(8, 2).solve([-1.5])
    with pytest.raises(ValueError, match="positive"):
        rectangle_problem(4, 2).operators([1.0, -0.5])
    with pytest.raises(ValueError, match="L"):
        interval_closed_form(np.array([0.1]), -1.0)


def test_non_finite_boundary_data_is_rejected():
    p = boundary_problem(8, 3)
    with pytest.raises(ValueError, match="eps"):
        p.measure([np.nan, 1.0])
    with pytest.raises(ValueError, match="eps"):
        p.solve([0.0, np.inf])
    with pytest.raises(ValueError, match="eps"):
        boundary_closed_form(np.array([0.5]), [np.nan, 0.0])
    with pytest.raises(ValueError, match="s"):
        boundary_problem(8, 3, s=np.nan)


def test_other_bad_input():
    with pytest.raises(ValueError, match="s"):
        interval_problem(8, 2, s=lambda x: np.full_like(x, np.nan)).measure([1.0])
    with pytest.raises(TypeError, match="s"):
        boundary_problem(8, 3, s="hot")
    with pytest.raises(ValueError, match="n_basis"):
        boundary_problem(0, 3)
    with pytest.raises(ValueError, match="sensors"):
        boundary_problem(4, 5)  # more forces than basis functions: singular ECFM system
    with pytest.raises(ValueError, match="sensors"):
        boundary_problem(8, 1)  # fewer measurements than parameters
    with pytest.raises(ValueError, match="sensors"):
        interval_problem(8, [0.2, 1.3])
    with pytest.raises(ValueError, match="sensors"):
        rectangle_problem(2, 3)
    with pytest.raises(ValueError, match="width"):
        gaussian_source(0.5, 0.0, 1.0)
    with pytest.raises(ValueError, match="theta"):
        boundary_problem(8, 3).field(np.zeros(3), np.array([0.5]))
