"""Pseudo-likelihood fits of replicated data: the three estimators (paper Section 3.3).

A stochastic Galerkin system :math:`R(\\Theta; \\epsilon, \\lambda) = 0` (Eq. pce; the
forces :math:`\\Gamma\\lambda` are deterministic) predicts at the sensors the random
values :math:`v_i(\\omega) = \\mathcal M_{ij}\\Theta_{jk}\\Psi_k(\\omega)` with mean and
variance (Eq. stats)

.. math::

    \\mu_i = \\mathcal M_{ij}\\Theta_{jk}\\,\\mathbb E[\\Psi_k], \\qquad
    \\sigma_i^2 = \\mathcal M_{ij}\\Theta_{jk}\\mathcal M_{ip}\\Theta_{pq}
        \\mathbb E[\\Psi_k\\Psi_q] - \\mu_i^2 .

Replicated data ``v`` (C, D) are scored by the Gaussian negative log pseudo-likelihood
(Eq. Lam)

.. math::

    \\Lambda(\\epsilon, \\lambda) = \\sum_{i=1}^C\\sum_{j=1}^D \\tfrac12\\log 2\\pi\\sigma_i^2
        + \\frac{(v_{ij} - \\mu_i)^2}{2\\sigma_i^2},

whose gradients (Eq. gradlam) follow from the moment sensitivities (Eq. sens_stats)
through :math:`\\partial\\Theta/\\partial\\lambda` (Eq. stochastic_sens) and
:math:`\\partial\\Theta/\\partial\\epsilon`. The inverse problem (Eq. stochastic_model)

.. math::

    \\min_{\\epsilon,\\lambda} \\tfrac12\\|\\lambda\\|^2 \\quad \\text{s.t.}\\quad
    \\partial\\Lambda/\\partial\\lambda = 0

is solved three ways by :func:`~ecfm_uq.inverse.fit` of a
:class:`~ecfm_uq.inverse.ReplicatedProblem` (:func:`fit_replicated_problem`):

``"inner-outer"``
    the ECFM structure: for each :math:`\\epsilon` the forces
    :math:`\\lambda^*(\\epsilon) = \\arg\\min_\\lambda \\Lambda` (a globalized Newton
    solve, checked to be a minimum), then :math:`\\min_\\epsilon \\tfrac12
    \\|\\lambda^*(\\epsilon)\\|^2` with the gradient from the implicit function theorem
    :math:`d\\lambda^*/d\\epsilon = -(\\partial^2\\Lambda/\\partial\\lambda^2)^{-1}
    \\partial^2\\Lambda/\\partial\\lambda\\partial\\epsilon`;
``"penalty"``
    the paper's unconstrained surrogate :math:`\\min_{\\epsilon,\\lambda}
    \\log(\\tfrac12\\|\\lambda\\|^2) + \\alpha\\Lambda` with SLSQP. Its first term is
    unbounded below as :math:`\\lambda \\to 0`; see :func:`fit_replicated_problem`;
``"standard"``
    maximum pseudo-likelihood over :math:`\\epsilon` with :math:`\\lambda = 0`.

The pieces: sensor moments and :math:`\\Lambda` of given moments in
:mod:`ecfm_uq.inverse.problems.moments`, :math:`\\Lambda(\\epsilon, \\lambda)` and its
derivatives in :mod:`ecfm_uq.inverse.problems.pseudo_likelihood`, the inner force solve in
:mod:`ecfm_uq.inverse.formulations.forces`.
"""

from __future__ import annotations

import copy
import numbers
import warnings

import numpy as np
import scipy.optimize as sopt

from ..._validation import check_positive
from ...errors import ConvergenceError
from ..core.convergence import (
    DECREMENT_TOL,
    Optimality,
    at_bound,
    bounds_arrays,
)
from ..core.details import InnerOuterDetails, PenaltyDetails, ReplicatedDetails
from ..core.fitter import Outcome
from ..core.result import Uncertainty
from ..problems.moments import moment_verdict, replicate_statistics
from ..statistics.uncertainty import estimate_uncertainty
from .forces import optimal_forces
from .replicated_status import (
    FAILURES,
    at_inner_resolution,
    eps_optimality,
    penalty_eps_newton,
)

__all__ = ["fit_replicated_problem"]

FORMULATIONS = ("inner-outer", "penalty", "standard")


_FAILURES = FAILURES


class _Tracker:
    """History of successful evaluations and the failures met by an optimizer."""

    def __init__(self):
        self.eps, self.loss, self.failures = [], [], []
        self.best = None  # (loss, x, payload) with the lowest loss

    def record(self, x, eps, loss, payload):
        self.eps.append(np.array(eps, dtype=float))
        self.loss.append(float(loss))
        if self.best is None or loss < self.best[0]:
            self.best = (float(loss), np.array(x, dtype=float), payload)

    def final(self, x, evaluate):
        """``evaluate(x) -> (loss, payload)`` at the optimizer's answer; if that fails,
        fall back to the best successful evaluation and report it (``ok=False``)."""
        try:
            loss, payload = evaluate(x)
            return np.array(x, dtype=float), loss, payload, True
        except _FAILURES as e:
            self.failures.append(f"final point: {e}")
            if self.best is None:
                raise ConvergenceError(f"no successful evaluation; last failure: {e}") from e
            loss, xb, payload = self.best
            return xb, loss, payload, False


def _trust_region(fun, eps0, bounds, gtol, maxiter, trust_radius):
    """``scipy.optimize.minimize(method="trust-constr")`` with a first step of at most
    ``trust_radius``.

    A bounded first step matters: :math:`\\Lambda(\\epsilon, 0)` is not convex (for the
    beam it falls again as the load nears buckling, where the predicted variance blows
    up), and line-search methods such as L-BFGS-B take a first step of unit length along
    the gradient, which can jump over the physically relevant minimum (for the beam
    from eps0 = 0.5 straight to the upper bound). ``gtol`` is relative to the gradient
    at the start.

    trust-constr also stops when the trust radius falls below ``xtol``. That is what
    happens when trial points keep failing (``fun`` returns ``inf`` where the forward or
    inner solve fails): the radius shrinks onto the edge of the solvable region. Such a
    stop next to a failed trial (within 1e-6 of the answer, relative) is said in the
    message; whether the point is an optimum is decided by :func:`eps_optimality`, never
    by trust-constr's own flag.

    With bounds, trust-constr is an interior-point method: an estimate held at a bound is
    returned a barrier's distance inside it (1e-4 of the box on a test problem), where the
    gradient still points out of the box and no optimality test can hold. Such a point is
    moved onto the bound (:func:`_onto_bounds`) when that does not raise the objective.
    """
    failed = []  # the trial points where the objective could not be evaluated

    def tracked(x):
        z, g = fun(x)
        if not np.isfinite(z):
            failed.append(np.array(x, dtype=float))
        return z, g

    z0, g0 = tracked(np.array(eps0, dtype=float))
    if not np.isfinite(z0):
        raise ConvergenceError(
            f"the objective cannot be evaluated at the start eps0={eps0} (the forward or "
            "inner solve fails there); choose a start where the model can be solved"
        )
    scale = max(1.0, float(np.abs(g0).max()))
    b = None if bounds is None else sopt.Bounds(*bounds_arrays(bounds, len(eps0)))
    with warnings.catch_warnings():
        # trust-constr warns when it swaps its bound-handling method; not a failure
        warnings.simplefilter("ignore", UserWarning)
        res = sopt.minimize(
            tracked,
            eps0,
            jac=True,
            hess=sopt.BFGS(),
            method="trust-constr",
            bounds=b,
            options={
                "gtol": gtol * scale,
                "xtol": 1e-12,
                "maxiter": maxiter,
                "initial_tr_radius": trust_radius,
                # a small barrier: the default (0.1) biases interior optima by ~1e-5
                "initial_barrier_parameter": 1e-8,
                "initial_barrier_tolerance": 1e-8,
            },
        )
    near = 1e-6 * max(1.0, float(np.linalg.norm(res.x)))
    if res.status == 2 and any(np.linalg.norm(x - res.x) <= near for x in failed):
        res.message = (
            f"{res.message} (the trust region collapsed onto the edge of the region where "
            "the model can be solved: trial steps next to it failed)"
        )
    if bounds is not None:
        _onto_bounds(res, tracked, bounds)
    return res


#: how far inside a bound (relative to the box's width, or to the parameter when a side is
#: open) an interior-point answer is taken to be held at it (see :func:`_onto_bounds`)
_BARRIER_GAP = 1e-3


def _onto_bounds(res, fun, bounds):
    """Move trust-constr's answer ``res.x`` onto the bounds the gradient pushes it against.

    Parameters within ``_BARRIER_GAP`` of a bound, with the gradient pointing out of the
    box there, are set to the bound; the move is kept if the objective is finite there,
    no larger, and its gradient still points out of the box (a KKT multiplier of the right
    sign), so the status test sees the bound as active.
    """
    x = np.array(res.x, dtype=float)
    g = np.asarray(res.grad, dtype=float)
    moved, sign = x.copy(), {}  # sign: +1 held at the lower bound (g > 0), -1 at the upper
    for k, side in at_bound(x, bounds, rtol=_BARRIER_GAP):
        if side == "lower" and g[k] > 0:
            moved[k], sign[k] = bounds[k][0], 1.0
        elif side == "upper" and g[k] < 0:
            moved[k], sign[k] = bounds[k][1], -1.0
    if not sign:
        return
    z, gm = fun(moved)
    if np.isfinite(z) and z <= res.fun and all(sign[k] * gm[k] > 0 for k in sign):
        res.x, res.fun, res.grad = moved, z, np.asarray(gm, dtype=float)
        res.message = f"{res.message} (moved onto the bounds it was held against)"


def _fit_standard(like, eps0, bounds, maxiter, gtol=1e-8, trust_radius=0.1, **_):
    sysm = like.system
    tr = _Tracker()

    def fun(eps):
        try:
            p = like.evaluate(eps, None, order=1)
        except _FAILURES as e:
            tr.failures.append(str(e))
            return np.inf, np.zeros(sysm.n_eps)
        tr.record(eps, eps, p.value, p)
        return p.value, p.grad_eps

    res = _trust_region(fun, eps0, bounds, gtol, maxiter, trust_radius)

    def evaluate(x):
        p = like.evaluate(x, None, order=1)
        return p.value, p

    x, loss, p, ok = tr.final(res.x, evaluate)

    def gradient(e):
        return like.evaluate(e, None, order=1).grad_eps

    extra = {"lam": np.zeros(sysm.n_forces), "stationarity": (loss, p.grad_eps, gradient)}
    return res, x, loss, p, ok, tr, extra


def _fit_inner_outer(
    like, eps0, bounds, maxiter, gtol=1e-8, lam0=None, trust_radius=0.1, inner_tol=1e-15, **_
):
    sysm = like.system
    tr = _Tracker()
    state = {"lam": like.forces(lam0), "inner_nit": 0}

    def inner(eps):
        # Lambda(eps, .) is not convex and has spurious local minima at large forces
        # (inflated variances absorbing the misfit); a warm start can land on one when
        # eps jumps. Take the lower Lambda of the zero-force and the warm start.
        found = [optimal_forces(like, eps, None, tol=inner_tol)]
        if np.any(state["lam"] != 0):
            found.append(optimal_forces(like, eps, state["lam"], tol=inner_tol))
        state["inner_nit"] += sum(fs.nit for fs in found)
        good = [fs for fs in found if fs.success]
        if not good:
            raise ConvergenceError(f"inner solve at eps={eps}: {found[0].message}")
        return min(good, key=lambda fs: fs.point.value)

    def fun(eps):
        try:
            fs = inner(eps)
        except _FAILURES as e:
            tr.failures.append(str(e))
            return np.inf, np.zeros(sysm.n_eps)
        state["lam"] = fs.lam
        z = 0.5 * float(fs.lam @ fs.lam)
        tr.record(eps, eps, z, fs)
        return z, fs.dlam_deps.T @ fs.lam

    res = _trust_region(fun, eps0, bounds, gtol, maxiter, trust_radius)

    def evaluate(x):
        fs = inner(x)
        return 0.5 * float(fs.lam @ fs.lam), fs

    x, loss, fs, ok = tr.final(res.x, evaluate)

    def gradient(e):  # the branch of lambda* through the estimate's forces
        f = optimal_forces(like, e, fs.lam, tol=inner_tol)
        if not f.success:
            raise ConvergenceError(f"inner solve at eps={e}: {f.message}")
        return f.dlam_deps.T @ f.lam

    g = None if fs.dlam_deps is None else fs.dlam_deps.T @ fs.lam
    extra = {
        "lam": fs.lam,
        "stationarity": (loss, g, gradient),
        "inner_message": fs.message,
        "inner_nit": state["inner_nit"],
        "hess_lam_min_eig": fs.min_hess_eig,
        "hess_lam_cond": fs.hess_cond,
        "dlam_deps": fs.dlam_deps,
    }
    return res, x, loss, fs.point, ok, tr, extra


def _fit_penalty(like, eps0, bounds, maxiter, ftol=1e-8, lam0=None, penalty=100.0, **_):
    sysm = like.system
    m, C = sysm.n_eps, sysm.n_forces
    alpha = check_positive("penalty", penalty)
    if lam0 is None:
        lam0 = np.full(C, 1e-3)
    lam0 = like.forces(lam0)
    if not np.any(lam0):
        raise ValueError(
            "`lam0` must be nonzero for the penalty form: log(0.5 ||lam||^2) is -inf at lam = 0"
        )
    tr = _Tracker()

    def objective(x):
        eps, lam = x[:m], x[m:]
        half = 0.5 * float(lam @ lam)
        if half <= 0.0:
            raise ConvergenceError("reached lam = 0 exactly, where log(0.5 ||lam||^2) = -inf")
        p = like.evaluate(eps, lam, order=1)
        z = np.log(half) + alpha * p.value
        g = np.concatenate([alpha * p.grad_eps, lam / half + alpha * p.grad_lam])
        return z, g, p

    def fun(x):
        try:
            z, g, p = objective(x)
        except _FAILURES as e:
            tr.failures.append(str(e))
            return np.inf, np.zeros_like(x)
        tr.record(x, x[:m], z, p)
        return z, g

    b = None if bounds is None else list(bounds) + [(None, None)] * C
    res = sopt.minimize(
        fun,
        np.concatenate([eps0, lam0]),
        jac=True,
        method="SLSQP",
        bounds=b,
        options={"ftol": ftol, "maxiter": maxiter},
    )
    x, loss, p, ok = tr.final(res.x, lambda x: objective(x)[::2])
    lam = x[m:]

    def gradient(e):  # alpha Lambda(., lam) at the returned forces
        return alpha * like.evaluate(e, lam, order=1).grad_eps

    # the forces' own condition: along lam -> t lam the objective's slope in log t is
    # 2 + alpha lam . dLambda/dlam, zero at a minimum; down the lam -> 0 valley the log term
    # dominates and it is 2 (the objective falls without bound as the forces shrink)
    slope = float(2.0 + alpha * lam @ p.grad_lam) if ok else None
    extra = {
        "lam": lam,
        "stationarity": (alpha * p.value, alpha * p.grad_eps, gradient),
        "penalty": alpha,
        "log_force_term": float(np.log(0.5 * lam @ lam)),
        "grad_lam_norm": float(np.linalg.norm(p.grad_lam)),
        "force_scaling_slope": slope,
        "slsqp_status": int(res.status),
    }
    return res, x, loss, p, ok, tr, extra


# the penalty form's force-scaling slope (objective per unit log of the forces' scale) that
# still counts as a minimum: SLSQP's local minima on the beam's 50 seed data sets reach
# at most 0.0074; the lam -> 0 valley has 2
_FORCE_SCALING_TOL = 0.1


def _force_scaling(opt, slope):
    """The penalty form's test of its forces, after :func:`eps_optimality`: a minimum
    along :math:`\\lambda \\to t\\lambda` (slope 0), not the :math:`\\lambda \\to 0`
    valley (slope 2)."""
    if not opt.converged or abs(slope) <= _FORCE_SCALING_TOL:
        return opt
    return Optimality(
        False, abs(slope), "force scaling", _FORCE_SCALING_TOL,
        f"in the forces: the objective still falls as they shrink (slope {slope:.3g} "
        "per unit log of their scale; 0 at a minimum): the fit went down the lam -> 0 "
        "valley, where the penalty objective is unbounded below and eps is the "
        "standard estimate",
    )  # fmt: skip


_FITTERS = {
    "inner-outer": _fit_inner_outer,
    "penalty": _fit_penalty,
    "standard": _fit_standard,
}

#: the typed details (``result.extra``) of each
_DETAILS = {
    "inner-outer": InnerOuterDetails,
    "penalty": PenaltyDetails,
    "standard": ReplicatedDetails,
}


#: defaults of the pseudo-likelihood fits: ``tol`` is the status test's (the relative
#: Newton decrement, :func:`eps_optimality`); the optimizers' own stopping rules are
#: options: trust-constr's ``gtol`` (relative to the gradient at eps0) and SLSQP's ``ftol``
_DEFAULT_MAXITER = 200
_SYNONYMS = {"ecfm": "inner-outer"}
_DEFAULT_METHOD = {"standard": "trust-region", "inner-outer": "trust-region", "penalty": "SLSQP"}
_OPTIONS = {
    "standard": {"trust_radius": 0.1, "gtol": 1e-8},
    "inner-outer": {"trust_radius": 0.1, "gtol": 1e-8, "lam0": None, "inner_tol": 1e-15},
    "penalty": {"lam0": None, "penalty": 100.0, "ftol": 1e-8},
}


def fit_replicated_problem(problem, eps0, s):
    """:func:`~ecfm_uq.inverse.fit` for a :class:`~ecfm_uq.inverse.problems.galerkin.ReplicatedProblem`:
    an :class:`~ecfm_uq.inverse.core.fitter.Outcome` (the Newton decrement in eps measured
    at the returned point; the entry point decides the status and builds the result).

    Formulations: ``"inner-outer"`` (or ``"ecfm"``): :math:`\\min_\\epsilon
    \\tfrac12\\|\\lambda^*(\\epsilon)\\|^2` with :math:`\\lambda^* = \\arg\\min_\\lambda
    \\Lambda` (the faithful reading of Eq. stochastic_model; a trust-region quasi-Newton
    method outside, globalized Newton inside, gradient by the implicit function
    theorem); ``"penalty"``: the paper's :math:`\\min_{\\epsilon,\\lambda}
    \\log(\\tfrac12\\|\\lambda\\|^2) + \\alpha\\Lambda` by SLSQP; ``"standard"``:
    :math:`\\min_\\epsilon\\Lambda(\\epsilon, 0)` by the trust-region method. ``options``:
    ``trust_radius`` (the longest first step, in eps units), ``lam0`` (starting forces),
    ``inner_tol`` (Newton-decrement tolerance of the inner force solve), ``penalty``
    (the penalty form's alpha, 100 in the paper).

    Notes
    -----
    The penalty objective is unbounded below: as :math:`\\lambda\\to 0` the term
    :math:`\\log(\\tfrac12\\|\\lambda\\|^2)\\to-\\infty` while :math:`\\alpha\\Lambda` stays
    finite, so it has no minimizer. It can have local minima near the joint maximizer of
    the pseudo-likelihood over :math:`(\\epsilon, \\lambda)`, where the log term's pull
    toward zero forces balances :math:`\\alpha\\,\\partial\\Lambda/\\partial\\lambda`. What
    SLSQP returns depends on the start: either such a local minimum (for the beam, close
    to the inner-outer estimate) or a point on the way down the valley
    :math:`\\lambda\\to 0`, where the :math:`\\epsilon`-part reduces to the standard
    estimate :math:`\\arg\\min_\\epsilon\\Lambda(\\epsilon, 0)`. SLSQP's own success flag
    certifies neither; the result's ``status`` tests :math:`\\epsilon` (Newton decrement) and
    the forces (the objective's slope along :math:`\\lambda \\to t\\lambda`,
    :math:`2 + \\alpha\\lambda^T\\partial_\\lambda\\Lambda`: zero at a local minimum, 2 on
    the valley), so a stop on the valley is reported not converged.
    """
    formulation = _SYNONYMS.get(s.formulation, s.formulation)
    if formulation not in _FITTERS:
        raise ValueError(
            f"unknown `formulation` {s.formulation!r}; choose one of {list(FORMULATIONS)} "
            "('ecfm' is 'inner-outer')"
        )
    method = _DEFAULT_METHOD[formulation] if s.method == "auto" else s.method
    if method != _DEFAULT_METHOD[formulation]:
        raise ValueError(
            f"formulation={formulation!r} is solved by method="
            f"{_DEFAULT_METHOD[formulation]!r} (or 'auto'), not {s.method!r}"
        )
    system = problem.system
    if formulation != "standard" and system.Gamma is None:
        raise ValueError(
            f"formulation={formulation!r} needs a system with constraint forces (Gamma)"
        )
    opts = s.take(_OPTIONS[formulation])
    if "penalty" in opts:
        penalty = opts["penalty"]
        if isinstance(penalty, bool) or not isinstance(penalty, numbers.Real):
            raise TypeError(f"`penalty` must be a positive number, got {penalty!r}")
    for name in ("trust_radius", "inner_tol", "gtol", "ftol"):
        if name in opts:
            opts[name] = check_positive(f"options[{name!r}]", opts[name])
    like = problem.likelihood
    solves_before = like.n_solves
    eps0 = system.check_eps(eps0)
    tol = DECREMENT_TOL if s.tol is None else s.tol
    maxiter = _DEFAULT_MAXITER if s.maxiter is None else s.maxiter
    res, x, loss, p, final_ok, tr, extra = _FITTERS[formulation](
        like, eps0, s.bounds, maxiter, **opts
    )
    lam = extra.pop("lam")
    stationarity = extra.pop("stationarity")
    msg = str(res.message)
    opt, optimality_solves = None, 0
    if final_ok:
        before = like.n_solves
        opt = eps_optimality(stationarity, x[: system.n_eps], s.bounds, tol)
        if formulation == "penalty":
            if not opt.converged:  # eps still moving where SLSQP stopped: finish it
                m, alpha = system.n_eps, extra["penalty"]
                eps_n, p_n = penalty_eps_newton(like, x[:m], lam, alpha, s.bounds, tol)
                if alpha * p_n.value < alpha * p.value:
                    x = np.concatenate([eps_n, lam])
                    p = p_n
                    loss = extra["log_force_term"] + alpha * p.value
                    extra["force_scaling_slope"] = float(2.0 + alpha * lam @ p.grad_lam)
                    stationarity = (alpha * p.value, alpha * p.grad_eps, stationarity[2])
                    opt = eps_optimality(stationarity, eps_n, s.bounds, tol)
                    msg += "; eps finished by Newton steps at the returned forces"
            opt = _force_scaling(opt, extra["force_scaling_slope"])
        elif formulation == "inner-outer" and not opt.converged and np.isfinite(opt.value):
            opt = at_inner_resolution(like, opt, stationarity, x[: system.n_eps], lam,
                                       s.bounds, opts.get("inner_tol", 1e-15))  # fmt: skip
        optimality_solves = like.n_solves - before
        msg += f" [{'converged' if opt.converged else 'NOT converged'}: {opt.message}]"
    if not final_ok:
        msg += f"; {tr.failures[-1]} -- returning the best point evaluated"
    if tr.failures:
        msg += f" ({len(tr.failures)} evaluations failed; first: {tr.failures[0]})"
    extra.update(
        force_norm=float(np.linalg.norm(lam)),
        neg_log_likelihood=p.value,
        grad_eps=p.grad_eps,
        mu=p.mu,
        var=p.var,
        n_solves=like.n_solves - solves_before - optimality_solves,
        optimality_solves=optimality_solves,
        n_failures=len(tr.failures),
    )
    eps_hat = np.asarray(x[: system.n_eps], dtype=float)
    verdict = moment_verdict(
        p.mu, p.var, like.v, alpha=s.alpha, at_bound=at_bound(eps_hat, s.bounds)
    )
    if verdict.consistent is False or verdict.identifiability:
        msg += f" [{verdict.message}]"
    if not s.uncertainty:
        unc = Uncertainty.failed("not computed (uncertainty=False)")
    else:
        unc = _likelihood_uncertainty(like, formulation, eps_hat, lam)
    nfev = int(getattr(res, "nfev", 0) or 0)
    return Outcome(
        uncertainty=unc,
        eps=eps_hat,
        loss=float(loss),
        opt=opt,
        exhausted=int(res.nit) >= maxiter,
        # a model that cannot be solved at the returned point is a measured failure
        failure=None if final_ok else msg,
        message=msg,
        nit=int(res.nit),
        nfev=nfev,
        njev=int(getattr(res, "njev", 0) or nfev),
        label=f"likelihood-{formulation}",
        method=method,
        eps_history=np.array(tr.eps).reshape(-1, system.n_eps),
        loss_history=np.array(tr.loss),
        state=p.Theta,
        forces=lam,
        extra=_DETAILS[formulation](**extra),
        verdict=verdict,
    )


# --------------------------------------------------------------------------------------
# uncertainty of the estimates (issue 13): delta method on the replicate statistics
# --------------------------------------------------------------------------------------
def _at_statistics(like, w):
    """A copy of ``like`` whose data statistics are ``w = (vbar, m)`` (see
    :func:`replicate_statistics`); the estimate as a function of the data."""
    new = copy.copy(like)
    new.vbar = np.asarray(w[: like.C], dtype=float)
    new.ss = like.D * np.asarray(w[like.C :], dtype=float)
    return new


#: Newton-decrement tolerance of the inner solves inside the uncertainty's finite
#: differences: their step is 1e-6, so the forces must be exact to far below that (with the
#: fits' 1e-15 the covariance is off by ~1e-5 relative; quadratic convergence makes the
#: extra digits one more Newton step)
_UNCERTAINTY_INNER_TOL = 1e-24


def _likelihood_uncertainty(like, formulation, eps, lam):
    """The :class:`~ecfm_uq.inverse.core.result.Uncertainty` of a pseudo-likelihood estimate.

    The optimality condition is differentiated implicitly
    (:func:`~ecfm_uq.inverse.statistics.uncertainty.implicit_covariance`) in the replicate
    statistics ``w``, with their sample covariance (:func:`replicate_statistics`): a
    sandwich
    covariance, valid although the Gaussian pseudo-likelihood is not the data's
    distribution. Student-t intervals with D - 1 degrees of freedom (the covariance is
    estimated from D replicates).
    """
    if formulation == "penalty":
        return Uncertainty.failed(
            "uncertainty not computed: the penalty objective has no minimizer (it is "
            "unbounded below as lam -> 0), so no optimality condition defines the estimate; "
            "use formulation='inner-outer' or 'standard'"
        )
    if formulation == "standard":

        def grad(e, w):
            return _at_statistics(like, w).evaluate(e, None, order=1).grad_eps

    else:

        def grad(e, w):
            fs = optimal_forces(_at_statistics(like, w), e, lam, tol=_UNCERTAINTY_INNER_TOL)
            if not fs.success:
                raise ConvergenceError(f"inner solve at eps={e}: {fs.message}")
            return fs.dlam_deps.T @ fs.lam

    w, Sigma_w = replicate_statistics(like.v)
    return estimate_uncertainty(
        grad, eps, w, Sigma_w, "replicates", dof=like.D - 1, rel_step=1e-4, stencil=4
    )
