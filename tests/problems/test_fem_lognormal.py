"""Lognormal diffusion on scikit-fem by stochastic Galerkin in Hermite chaos (issue 22 item 4).

References, each independent of the Galerkin solve: scikit-fem's own assembly of the
sampled conductivity, a Gauss-Legendre Nystrom solution of the separable covariance's
eigenproblem (for the KL), tensor Gauss-Hermite collocation and Monte Carlo over
deterministic ``splu`` solves, and the deterministic solve with a = exp(m).
"""

import numpy as np
import pytest
import scipy.sparse.linalg as spla
from scipy.special import roots_legendre

pytest.importorskip("skfem")

import skfem  # noqa: E402
from skfem.helpers import dot, grad  # noqa: E402

from ecfm_uq.chaos import ChaosBasis  # noqa: E402
from ecfm_uq.mc import mc_moments  # noqa: E402
from ecfm_uq.problems.fem_lognormal import build_fem_lognormal, kl_expansion  # noqa: E402
from ecfm_uq.system import solve_steady  # noqa: E402

CELLS, N_KL = 6, 2  # 25 unknowns, two KL modes (half the field's variance at l = 0.5)


def splu_solve(problem, xi):
    return spla.splu(problem.stiffness(xi).tocsc()).solve(problem.F)


def galerkin_moments(problem):
    sol = solve_steady(problem.system, [0.0])
    assert sol.success, sol.message
    return sol, problem.system.mean(sol.Theta), problem.system.variance(sol.Theta)


def rel(a, b):
    return np.abs(a - b).max() / np.abs(b).max()


@pytest.fixture(scope="module")
def collocation():
    # 20^2 Gauss-Hermite nodes: converged to ~1e-12 for this field (checked against 16^2)
    base = build_fem_lognormal(CELLS, 0, N_KL)
    out = []
    for n in (20, 16):
        x, w = ChaosBasis(0, N_KL, germ="hermite").quadrature(n)
        U = np.array([splu_solve(base, xi) for xi in x])
        mean = w @ U
        out.append((mean, w @ (U - mean) ** 2))
    (m20, v20), (m16, v16) = out
    assert rel(m16, m20) < 1e-10 and rel(v16, v20) < 1e-8
    return m20, v20


def test_stiffness_equals_scikit_fem_assembly_of_the_sampled_conductivity():
    problem = build_fem_lognormal(CELLS, 1, N_KL)
    basis = problem.fem_basis

    @skfem.BilinearForm
    def form(u, v, w):
        return np.exp(w.g) * dot(grad(u), grad(v))

    for xi in ([0.0, 0.0], [0.7, -1.2], [-2.0, 1.5]):
        g = basis.interpolate(problem.log_conductivity(np.array(xi)))
        K = skfem.asm(form, basis, g=g)[problem.interior][:, problem.interior]
        assert abs(K - problem.stiffness(xi)).max() < 1e-12 * abs(K).max()


def test_chaos_terms_sum_to_the_sampled_stiffness():
    # K(xi) = sum_alpha K_alpha phi_alpha(xi) once the coefficient order is high enough
    problem = build_fem_lognormal(CELLS, 0, N_KL, coef_order=14)
    xi = np.array([0.8, -0.6])
    phi = problem.coef_basis.evaluate(xi[None, :])[0]
    K = sum(c * Ka for c, Ka in zip(phi, problem.K_terms, strict=True))
    Kx = problem.stiffness(xi)
    assert abs(K - Kx).max() < 1e-12 * abs(Kx).max()


def test_deterministic_system_is_the_sample_solved_by_the_engine():
    problem = build_fem_lognormal(CELLS, 1, N_KL)
    xi = np.array([1.1, -0.4])
    sol = solve_steady(problem.deterministic_system(xi), [0.2])
    assert sol.success and sol.solver == "sparse-direct"
    u = spla.splu((10**0.2 * problem.stiffness(xi)).tocsc()).solve(problem.F)
    np.testing.assert_allclose(sol.Theta[:, 0], u, rtol=1e-10)


def test_kl_modes_are_mass_orthonormal_eigenpairs_of_the_covariance_operator():
    x = np.linspace(0, 1, 5)
    mesh = skfem.MeshTri.init_tensor(x, x)
    basis = skfem.Basis(mesh, skfem.ElementTriP1())
    M = skfem.asm(skfem.BilinearForm(lambda u, v, w: u * v), basis)
    n, s, ell = mesh.p.shape[1], 0.7, 0.3
    lam, phi = kl_expansion(mesh.p.T, M, n, sigma=s, corr_length=ell)
    np.testing.assert_allclose(phi.T @ (M @ phi), np.eye(n), atol=1e-10)
    assert np.all(np.diff(lam) <= 0)
    # M C M phi = lam M phi  <=>  eigenvalues of C M (a non-symmetric eigensolve)
    X = mesh.p.T
    C = s**2 * np.exp(-np.linalg.norm(X[:, None] - X[None, :], axis=-1) / ell)
    ref = np.sort(np.linalg.eigvals(C @ M.toarray()).real)[::-1]
    np.testing.assert_allclose(lam, ref, rtol=1e-9, atol=1e-12)
    # leading modes only: the same ones
    lam3, phi3 = kl_expansion(mesh.p.T, M, 3, sigma=s, corr_length=ell)
    np.testing.assert_allclose(lam3, lam[:3], rtol=1e-12)
    np.testing.assert_allclose(np.abs(phi3.T @ (M @ phi[:, :3])), np.eye(3), atol=1e-8)


def test_kl_eigenvalues_converge_to_the_separable_kernel_like_h_squared():
    # exp(-r^2 / 2l^2) = exp(-dx^2 / 2l^2) exp(-dy^2 / 2l^2): the 2-D eigenvalues are
    # products of 1-D ones, computed here by a 80-point Gauss-Legendre Nystrom method
    ell = 0.5
    z, w = roots_legendre(80)
    z, w = (z + 1) / 2, w / 2
    C = np.exp(-0.5 * (z[:, None] - z[None, :]) ** 2 / ell**2)
    l1 = np.linalg.eigvalsh(np.sqrt(w)[:, None] * C * np.sqrt(w)[None, :])
    exact = np.sort(np.outer(l1, l1).ravel())[::-1][:4]
    errs = []
    for n_cells in (12, 24):
        problem = build_fem_lognormal(
            n_cells, 0, 4, sigma=1.0, corr_length=ell, covariance="squared-exponential"
        )
        errs.append(np.abs(problem.kl_values / exact - 1).max())
    # P1 interpolation of the kernel: O(h^2)
    assert 3.0 < errs[0] / errs[1] < 5.0
    assert errs[1] < 1e-2


def test_galerkin_mean_and_variance_within_monte_carlo_standard_errors():
    problem = build_fem_lognormal(CELLS, 4, N_KL)
    sol, m, v = galerkin_moments(problem)
    assert sol.solver == "cg+mean"
    rng = np.random.default_rng(2024)
    U = np.array([splu_solve(problem, xi) for xi in rng.standard_normal((3000, N_KL))])
    mo = mc_moments(U)
    assert np.all(np.abs(mo.mean - m) < 4 * mo.se_mean)
    assert np.all(np.abs(mo.var - v) < 4 * mo.se_var)
    # in L2: ||mean_MC - mean_G||_M against its standard deviation sqrt(tr(M Cov) / n)
    M, n = problem.mass, U.shape[0]
    for samples, est in ((U, m), ((U - mo.mean) ** 2 * n / (n - 1), v)):
        d = samples - samples.mean(axis=0)
        tr = np.einsum("si,si->", d, (M @ d.T).T) / (n - 1)
        e = samples.mean(axis=0) - est
        assert np.sqrt(e @ (M @ e)) < 3 * np.sqrt(tr / n)


def test_truncation_error_falls_spectrally_with_the_order(collocation):
    mref, vref = collocation
    err_m, err_v = [], []
    for p in range(1, 5):
        _, m, v = galerkin_moments(build_fem_lognormal(CELLS, p, N_KL))
        err_m.append(rel(m, mref))
        err_v.append(rel(v, vref))
    err_m, err_v = np.array(err_m), np.array(err_v)
    assert np.all(err_m[1:] < err_m[:-1] / 5) and np.all(err_v[1:] < err_v[:-1] / 5)
    assert err_v[-1] < 1e-3  # variance truncation error below 1e-3 by order 4


def test_zero_sigma_reproduces_the_deterministic_solve_with_exp_mean():
    m0 = 0.3
    problem = build_fem_lognormal(CELLS, 2, N_KL, mean=m0, sigma=0.0)
    sol, mean, var = galerkin_moments(problem)
    basis = problem.fem_basis

    @skfem.BilinearForm
    def laplace(u, v, w):
        return dot(grad(u), grad(v))

    K = skfem.asm(laplace, basis)[problem.interior][:, problem.interior]
    u = spla.spsolve((np.exp(m0) * K).tocsc(), problem.F)
    np.testing.assert_allclose(mean, u, rtol=1e-9)
    assert np.abs(sol.Theta[:, 1:]).max() < 1e-12 * np.abs(u).max()
    np.testing.assert_allclose(var, 0.0, atol=1e-20)


def test_eps0_shifts_the_field_mean_by_eps0_ln10():
    shift = 0.4
    a = build_fem_lognormal(CELLS, 2, N_KL)
    b = build_fem_lognormal(CELLS, 2, N_KL, mean=shift)
    Ta = solve_steady(a.system, [shift / np.log(10.0)], tol=1e-12).Theta
    Tb = solve_steady(b.system, [0.0], tol=1e-12).Theta
    np.testing.assert_allclose(Ta, Tb, rtol=1e-8, atol=1e-12 * np.abs(Tb).max())


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"sigma": -0.1}, "`sigma` must be >= 0"),
        ({"corr_length": 0.0}, "corr_length"),
        ({"covariance": "matern"}, "covariance"),
        ({"n_kl": 50}, "`n_kl` must be at most"),
        ({"coef_order": -1}, "coef_order"),
    ],
)
def test_bad_input_names_the_argument(kwargs, match):
    args = {"n_cells": 4, "order": 1, "n_kl": 2} | kwargs
    with pytest.raises(ValueError, match=match):
        build_fem_lognormal(**args)


def test_bad_germ_point_names_xi():
    problem = build_fem_lognormal(4, 1, 2)
    with pytest.raises(ValueError, match="xi"):
        problem.stiffness([0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="xi"):
        problem.stiffness([np.nan, 0.0])


def test_docs_example_runs_and_prints_what_it_says():
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[2] / "docs" / "fem.md").read_text()
    blocks = [b for b in re.findall(r"```python\n(.*?)```", text, re.S) if "fem_lognormal" in b]
    assert len(blocks) == 1
    ns = {}
    exec(compile(blocks[0], "fem.md", "exec"), ns)
    problem, sol = ns["problem"], ns["sol"]
    np.testing.assert_allclose(problem.kl_values, [0.1007, 0.0273, 0.0272, 0.0111], atol=6e-5)
    assert round(problem.kl_fraction, 3) == 0.665
    assert (
        sol.success
        and sol.solver == "cg+mean"
        and (problem.system.P, len(problem.K_terms)) == (70, 495)
    )
    assert ns["u_nodes"].shape == (problem.n_nodes,)
