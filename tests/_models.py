"""Small models shared by several test modules (imported through conftest's path entry)."""

import numpy as np
import scipy.sparse as sp

from ecfm_uq.chaos import ChaosBasis, weighted_gram
from ecfm_uq.spectral import SineBasis, hat_forces, load, mass, sensor_matrix, stiffness
from ecfm_uq.system import (
    Coefficient,
    GalerkinSystem,
    LinearTerm,
    LoadTerm,
    NonlinearTerm,
    QuadraticTerm,
    solve_steady,
)


def fd_stiffness(N, weight=np.ones_like):
    """1-D P1 stiffness with a cell weight (sparse, SPD)."""
    h = 1.0 / (N + 1)
    a = weight((np.arange(N + 1) + 0.5) * h) / h
    return sp.diags([-a[1:-1], a[:-1] + a[1:], -a[1:-1]], [-1, 0, 1], format="csr")


def diffusion(N=20, dim=2, order=2, sparse=True, sigma=0.3, n_forces=3):
    """-(10^eps0 + sum_k sigma_k sin(k pi x)(w_k - 1/2)) u'' = eps1, with forces and mass."""
    basis = ChaosBasis(order, dim)
    conv = (lambda K: K) if sparse else (lambda K: K.toarray())
    terms = [
        LinearTerm(conv(fd_stiffness(N)), Coefficient.power10(0, sign=1.0), name="mean"),
    ]
    for k in range(dim):
        K = fd_stiffness(N, lambda x, k=k: sigma / (k + 1) * np.sin((k + 1) * np.pi * x))
        G = weighted_gram(basis, lambda w, k=k: (w[:, k] if w.ndim == 2 else w) - 0.5)
        terms.append(LinearTerm(conv(K), G=G, name=f"mode{k}"))
    terms.append(LoadTerm.scaled(np.full(N, 1.0 / (N + 1)), Coefficient.parameter(1)))
    idx = np.linspace(2, N - 3, n_forces).astype(int)
    Gamma = np.eye(N)[:, idx]
    M = sp.identity(N, format="csr") / (N + 1)
    return (
        GalerkinSystem(
            terms,
            2,
            basis=basis,
            Gamma=sp.csr_matrix(Gamma) if sparse else Gamma,
            M=M if sparse else M.toarray(),
        ),
        np.eye(N)[idx],
    )


def burgers_like(order, N=8):
    """Viscous Burgers-like model: a quadratic convection term, a viscosity spread by a
    uniform germ (order > 0) and a load scaled by eps0."""
    A = np.zeros((N, N, N))
    for i in range(N - 1):
        A[i, i, i + 1] = 0.5
        A[i + 1, i, i + 1] = -0.5
    K = (2 * np.eye(N) - np.eye(N, k=1) - np.eye(N, k=-1)) * 4.0
    basis = ChaosBasis(order, 1) if order else None
    G = None if not order else weighted_gram(basis, lambda w: 1.0 + 0.4 * (w[:, 0] - 0.5))
    terms = [
        LinearTerm(K) if G is None else LinearTerm(K, G=G),
        QuadraticTerm(A),
        LoadTerm.scaled(np.sin(np.linspace(0.3, 2.8, N)), Coefficient.parameter(0)),
    ]
    return GalerkinSystem(terms, 1, basis=basis, M=np.eye(N))


def logistic(order=0, spread=0.5):
    """u' = a(w) u (1 - u/K), a(w) = a (1 + spread (w - 1/2)) with a uniform germ w
    (order 0: deterministic), through the user-callback NonlinearTerm."""

    def rate(w, eps):
        return eps[0] * (1 + spread * (w[0] - 0.5)) if len(w) else eps[0]

    def residual(u, w, eps):
        return -rate(w, eps) * u * (1 - u / eps[1])

    def jacobian(u, w, eps):
        return np.array([[-rate(w, eps) * (1 - 2 * u[0] / eps[1])]])

    def eps_jacobian(u, w, eps):
        a = rate(w, eps)
        return np.array([[-a / eps[0] * u[0] * (1 - u[0] / eps[1]), -a * u[0] ** 2 / eps[1] ** 2]])

    term = NonlinearTerm(residual, jacobian, eps_jacobian=eps_jacobian, degree=3, size=1)
    basis = ChaosBasis(order, 1) if order else None
    return GalerkinSystem([term], 2, basis=basis, M=np.eye(1), name="logistic")


# --------------------------------------------------------------------------------------
# the borehole function with uniform inputs and its Sobol indices (issue 37)
# --------------------------------------------------------------------------------------
BOREHOLE_BOUNDS = np.array(
    [
        (0.05, 0.15),  # r_w
        (100.0, 50000.0),  # r
        (63070.0, 115600.0),  # T_u
        (990.0, 1110.0),  # H_u
        (63.1, 116.0),  # T_l
        (700.0, 820.0),  # H_l
        (1120.0, 1680.0),  # L
        (9855.0, 12045.0),  # K_w
    ]
)


def borehole(X):
    """The borehole function (Harper & Gupta 1983), x = (r_w, r, T_u, H_u, T_l, H_l, L, K_w)."""
    rw, r, Tu, Hu, Tl, Hl, L, Kw = np.asarray(X, dtype=float).T
    lg = np.log(r / rw)
    return 2 * np.pi * Tu * (Hu - Hl) / (lg * (1 + 2 * L * Tu / (lg * rw**2 * Kw) + Tu / Tl))


def borehole_indices(nodes=(10, 100, 5, 2, 8, 2, 8, 8)):
    """First-order and total Sobol indices of :func:`borehole`: (S, T), by quadrature.

    Tensor Gauss-Legendre rules of ``nodes`` points per input for the conditional
    variances, :math:`S_i = \\operatorname{Var}(E[f|x_i])/V` and
    :math:`T_i = E[\\operatorname{Var}(f|x_{\\sim i})]/V`; f is linear in H_u and H_l
    (two nodes are exact) and smooth elsewhere, its logarithm in r converging slowest. The
    default rule agrees with (14, 200, 6, 2, 10, 2, 10, 10) to 1e-14 in every index;
    (8, 60, 4, 2, 6, 2, 6, 6) to 1e-10 (0.8 s).
    """
    dim = len(nodes)
    pts, ws = [], []
    for (lo, hi), m in zip(BOREHOLE_BOUNDS, nodes, strict=True):
        x, w = np.polynomial.legendre.leggauss(m)
        pts.append(lo + (hi - lo) * (x + 1) / 2)
        ws.append(w / 2)
    grid = np.meshgrid(*pts, indexing="ij")
    Y = borehole(np.stack([g.ravel() for g in grid], axis=1)).reshape(nodes)
    del grid

    def integrate(A, axes):
        for d in sorted(axes, reverse=True):
            A = np.tensordot(A, ws[d], axes=([d], [0]))
        return A

    Yc = Y - integrate(Y, range(dim))
    Y2 = Yc**2
    V = integrate(Y2, range(dim))
    S, T = np.empty(dim), np.empty(dim)
    for i in range(dim):
        others = [d for d in range(dim) if d != i]
        S[i] = ws[i] @ integrate(Yc, others) ** 2 / V
        # E over the others of the variance in x_i
        cond = (
            np.tensordot(Y2, ws[i], axes=([i], [0])) - np.tensordot(Yc, ws[i], axes=([i], [0])) ** 2
        )
        for k in reversed(range(dim - 1)):
            cond = np.tensordot(cond, ws[others[k]], axes=([k], [0]))
        T[i] = cond / V
    return S, T


def ridge_rod():
    """Issue 37's ridge as a Galerkin rod: -kappa w'' + c w = s, kappa pi^2 = 50.5 (the
    operator singular at c = -50.5), 16 sine modes, read at five points in [0.2, 0.8] with
    hat forces there: ``(system, M)``."""
    B = SineBasis(16)
    xs = np.linspace(0.2, 0.8, 5)
    terms = [LinearTerm(50.5 / np.pi**2 * stiffness(B)), LinearTerm(mass(B),
             Coefficient.parameter(0)), LoadTerm.scaled(-load(B, np.ones_like),
             Coefficient.parameter(1))]  # fmt: skip
    return GalerkinSystem(terms, 2, Gamma=hat_forces(B, xs, 0.05)), sensor_matrix(B, xs)


def ridge_data(system, M, truth, n, seed=1):
    """The ``n``-th data set (from 0) of the stream ``default_rng(seed)``, 2 % noise:
    ``(y, sigma)``."""
    y0 = M @ solve_steady(system, truth, strict=True).Theta[:, 0]
    sigma = 0.02 * np.abs(y0).mean()
    rng = np.random.default_rng(seed)
    for _ in range(n + 1):
        y = y0 + sigma * rng.standard_normal(y0.size)
    return y, sigma
