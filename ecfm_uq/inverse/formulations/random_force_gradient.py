"""The exact gradient of the random-force ECFM's profiled marginal likelihood.

The estimate of :mod:`~ecfm_uq.inverse.formulations.random_forces` minimizes
:math:`p(\\epsilon) = \\ell(\\epsilon, \\hat g(\\epsilon))`, the marginal likelihood

.. math::

    \\ell = \\tfrac12 r^T S^{-1} r + \\tfrac12 \\log\\det S,\\qquad
    S = \\sigma^2 I + A\\,\\mathrm{diag}(g)\\,A^T,

with the force variances :math:`g` re-estimated at every :math:`\\epsilon`. Its gradient is

.. math::

    \\frac{dp}{d\\epsilon_j} = -w^T J_j - (w^T \\partial_j A)\\,(g \\circ A^T w)
    + \\mathrm{tr}(\\mathrm{diag}(g) A^T S^{-1} \\partial_j A)
    + \\frac{\\partial\\ell}{\\partial s}\\frac{ds}{d\\epsilon_j},\\qquad w = S^{-1} r,

(:math:`\\partial_j r = -J_j`). The last term is the shared prior's: :math:`g = \\tau^2` with
:math:`s = \\tau^2 a_0^2/\\sigma^2` the restricted-likelihood (REML) estimate, a stationary
point of :math:`f(s, \\epsilon) = 2(\\ell_R(0) - \\ell_R(s))`, so by the implicit function
theorem :math:`ds/d\\epsilon_j = -f_{s\\epsilon_j}/f_{ss}` (zero where :math:`\\hat s = 0`).
With :math:`H = AA^T/a_0^2`, :math:`Q` the projector onto the complement of the span of
:math:`J` and :math:`T = Q(I + sQHQ)^{-1}Q`, :math:`u = Tr`:
:math:`f_s = u^T H u/\\sigma^2 - \\mathrm{tr}(TH)`,
:math:`f_{ss} = -2u^T HTHu/\\sigma^2 + \\mathrm{tr}(THTH)`, and :math:`f_{s\\epsilon_j}` follows
from :math:`\\partial_j Q = -(Q\\,\\partial_j J\\,J^+ + (Q\\,\\partial_j J\\,J^+)^T)`,
:math:`\\partial_j T = \\partial_j Q\\,T + T\\,\\partial_j Q - sT(\\partial_j Q\\,H + \\partial_j H
+ H\\,\\partial_j Q)T` (and :math:`T J = 0`). The sparse prior's variances maximize
:math:`\\ell` itself at every :math:`\\epsilon`, so there the envelope theorem leaves the
first three terms.

The gradient needs :math:`\\partial A/\\partial\\epsilon` and :math:`\\partial J/\\partial\\epsilon`,
second derivatives of the state: differentiating :math:`R(\\Theta;\\epsilon) - \\Gamma\\lambda
= 0` twice, :math:`R_\\Theta\\,\\Theta_{\\lambda\\epsilon_j} = -D_j[R_\\Theta]\\,\\Theta_\\lambda`
and :math:`R_\\Theta\\,\\Theta_{\\epsilon\\epsilon_j} = -D_j[R_\\Theta\\,\\Theta_\\epsilon +
R_\\epsilon]`, with :math:`D_j` the derivative along the solution's tangent
:math:`(\\Theta_{\\epsilon_j}, e_j)`. The terms give first derivatives only (a coefficient
has no second derivative), so :math:`D_j` is a central difference of the residual's
Jacobian actions along that tangent -- no solve: one back-substitution with the converged
solve's factors for all the right-hand sides.
"""

from __future__ import annotations

import numpy as np

from ...system.solve.factors import cho_factor, cho_solve

__all__ = ["profiled_gradient", "second_sensitivities", "unit_column_svd"]

_STEP = 1e-5  # relative step of the tangent central differences (error ~ step^2)
_DENSE = 1000  # up to this many unknowns the Jacobian is assembled for its actions
_MACHINE_EPS = np.finfo(float).eps


def unit_column_svd(J):
    """The span of ``J`` from its unit columns: ``(norms, U, sv, Vt, rank)``, ``J``'s column
    norms, the full SVD of its nonzero columns scaled to unit norm and its numerical rank.

    The unit columns make the rank independent of the parameters' units and magnitudes (a
    parameter whose effect is merely small, e.g. a reaction rate 10^eps0 far below the
    diffusion, still explains its direction); the SVD finds the span where a column
    vanishes (QR without pivoting misplaces it). The error contrasts of
    :meth:`~ecfm_uq.inverse.formulations.random_forces.RandomForceModel.linearize` and the
    REML derivative here both stand on this one factorization.
    """
    norms = np.linalg.norm(J, axis=0)
    live = norms > 0
    Jn = J[:, live] / norms[live]
    U, sv, Vt = np.linalg.svd(Jn, full_matrices=True)
    rank = int(np.sum(sv > max(Jn.shape) * _MACHINE_EPS * sv[0])) if sv.size else 0
    return norms, U, sv, Vt, rank


def second_sensitivities(system, sol, dTh_e, dTh_l, M):
    """:math:`\\partial A/\\partial\\epsilon` and :math:`\\partial J/\\partial\\epsilon` at a
    converged steady solve.

    Parameters
    ----------
    system : GalerkinSystem
    sol : SteadySolution
        Converged, unconstrained (its factors serve the back-substitution).
    dTh_e : (N, P, n_eps) ndarray
        :math:`\\partial\\Theta/\\partial\\epsilon`.
    dTh_l : (N, P, F) ndarray
        :math:`\\partial\\Theta/\\partial\\lambda`.
    M : (C, N) array_like or sparse matrix
        The observation operator.

    Returns
    -------
    dA : (C, F, n_eps) ndarray
        :math:`\\mathcal M\\,\\partial^2\\mathbb E[\\theta]/\\partial\\lambda\\partial\\epsilon_j`.
    dJ : (C, n_eps, n_eps) ndarray
        ``dJ[:, k, j]`` :math:`= \\mathcal M\\,\\partial^2\\mathbb E[\\theta]/\\partial\\epsilon_k
        \\partial\\epsilon_j`.
    """
    N, P = system.shape
    m, F = dTh_e.shape[2], dTh_l.shape[2]
    eps, Theta = np.asarray(sol.eps, float), sol.Theta
    columns = np.concatenate([dTh_l, dTh_e], axis=2).reshape(N * P, F + m)

    def actions(Th, e):
        op = system.jacobian_operator(Th, e)
        if op.size <= _DENSE:  # assembled: one product instead of a Python loop
            out = op.to_dense() @ columns
        else:
            cols = columns.reshape(N, P, -1)
            out = np.column_stack([op.apply(cols[:, :, c]).ravel() for c in range(F + m)])
        out[:, F:] += system.eps_jacobian(Th, e)
        return out

    rhs = np.empty((N * P, m * (F + m)))
    for j in range(m):
        h = _STEP * max(1.0, abs(eps[j]))
        step = np.zeros(m)
        step[j] = h
        plus = actions(Theta + h * dTh_e[:, :, j], eps + step)
        minus = actions(Theta - h * dTh_e[:, :, j], eps - step)
        rhs[:, j * (F + m) : (j + 1) * (F + m)] = (plus - minus) / (2.0 * h)
    X = -sol.jacobian_solve(rhs).reshape(N, P, m, F + m)
    mean = np.asarray(M @ np.einsum("npjc,p->njc", X, system.E1).reshape(N, -1))
    mean = mean.reshape(-1, m, F + m)  # (C, j, column)
    dA = np.transpose(mean[:, :, :F], (0, 2, 1))
    dJ = np.transpose(mean[:, :, F:], (0, 2, 1))
    return dA, dJ


def profiled_gradient(lin, dA, dJ, sigma, g, s=None, a0=None):
    """:math:`dp/d\\epsilon` of the profiled marginal likelihood (module docstring).

    Parameters
    ----------
    lin : Linearization
        ``r``, ``A`` and ``J`` at the point.
    dA, dJ : ndarray
        From :func:`second_sensitivities`.
    sigma : float
        The noise standard deviation.
    g : (F,) ndarray
        The force variances at the point.
    s : float, optional
        The shared prior's REML estimate of the scaled variance (with ``a0``); ``None``
        for variances that maximize :math:`\\ell` itself (the sparse prior: envelope).
    a0 : float, optional
        The force-to-data scale of ``s``.

    Returns
    -------
    (n_eps,) ndarray, or ``None`` where the REML estimate is not differentiable in
    :math:`\\epsilon` (the span of :math:`J` is rank-deficient).
    """
    r, A, J = lin.r, lin.A, lin.J
    S = sigma**2 * np.eye(r.size) + (A * g) @ A.T
    chol = cho_factor(S)
    w = cho_solve(chol, r)
    SiA = cho_solve(chol, A)
    grad = -J.T @ w
    grad -= np.einsum("c,cfj,f->j", w, dA, g * (A.T @ w))
    grad += np.einsum("cf,cfj->j", SiA * g, dA)
    if s is None or s <= 0.0:
        return grad
    ds = _reml_derivative(lin, dA, dJ, sigma, s, a0)
    if ds is None:
        return None
    # d ell / ds with S = sigma^2 (I + s A A^T / a0^2)
    Hs = sigma**2 * (A @ A.T) / a0**2
    l_s = 0.5 * (np.sum(SiA * A) * sigma**2 / a0**2 - w @ Hs @ w)
    return grad + l_s * ds


def _reml_derivative(lin, dA, dJ, sigma, s, a0):
    """:math:`ds/d\\epsilon` of the REML estimate ``s`` (implicit function theorem)."""
    r, A, J = lin.r, lin.A, lin.J
    m = J.shape[1]
    norms, U, sv, Vt, rank = lin.svd  # linearize's unit_column_svd(J)
    live = norms > 0
    if rank < np.count_nonzero(live):
        return None
    K = U[:, rank:]
    Q = K @ K.T
    Jn_pinv = (Vt.T / sv) @ U[:, :rank].T  # (n_live, C)
    H = A @ A.T / a0**2
    B = K.T @ H @ K
    T = K @ np.linalg.solve(np.eye(K.shape[1]) + s * B, K.T)
    u = T @ r
    Hu = H @ u
    TH = T @ H
    f_ss = -2.0 * (Hu @ T @ Hu) / sigma**2 + np.sum(TH * TH.T)
    if not f_ss < 0.0:
        return None  # not a strict maximum: s is not differentiable there
    # every j at once, as stacks whose slices have the layouts of the separate products
    # (elementwise steps and per-slice matrix products: the same bits as a loop over j)
    dAs = np.moveaxis(dA, 2, 0)  # (m, C, F) views, each as strided as dA[:, :, j]
    X = np.ascontiguousarray(np.moveaxis(dJ[:, live, :], 2, 0)) / norms[live]
    E = np.ascontiguousarray(Q @ X) @ Jn_pinv
    dQ = -np.ascontiguousarray(E + np.swapaxes(E, 1, 2))
    dH = (dAs @ A.T + A @ np.swapaxes(dAs, 1, 2)) / a0**2
    dT = dQ @ T + T @ dQ - np.ascontiguousarray((s * T) @ (dQ @ H + dH + H @ dQ)) @ T
    du = dT @ r  # T J_j = 0: the contrasts do not see dr = -J_j
    ds = np.zeros(m)
    for j in range(m):
        f_se = (2.0 * (Hu @ du[j]) + u @ dH[j] @ u) / sigma**2 - np.sum(dT[j] * H)
        ds[j] = -(f_se - np.sum(T * dH[j])) / f_ss
    return ds
