"""Small models shared by several test modules (imported through conftest's path entry)."""

import numpy as np
import scipy.sparse as sp

from ecfm_uq.chaos import ChaosBasis, weighted_gram
from ecfm_uq.system import (
    Coefficient,
    GalerkinSystem,
    LinearTerm,
    LoadTerm,
    NonlinearTerm,
    QuadraticTerm,
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
