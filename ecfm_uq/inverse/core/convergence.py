"""Whether a fit converged, read from its optimality conditions: one decision, one place.

Every reduced fit (steady, dynamic; standard or ECFM; whatever optimizer ran it) asks
this module whether its returned point is an optimum, instead of trusting the message of
the library underneath (in the manner of PETSc's SNES convergence tests: a small, named
test with a reason a user can read). The tests are unit-free: multiplying the model's
equations, the data or a parameter by a positive constant changes no decision.

Least squares, :math:`z = \\tfrac12\\|r(\\epsilon)\\|^2` with Jacobian :math:`J`
(:func:`least_squares_optimality`)
    With :math:`Q_1` an orthonormal basis of the columns of :math:`J` (:math:`n`
    residuals, :math:`p` free parameters; computed here from the thin SVD of :math:`J`
    with its columns scaled to unit norm, which also gives the rank and the step below),
    the **relative offset** of Bates and Watts (1981)

    .. math::

        c = \\frac{\\|Q_1^T r\\| / \\sqrt p}{\\|r - Q_1 Q_1^T r\\| / \\sqrt{n - p}}

    compares the part of the residual the model could still remove (the Gauss-Newton
    step, :math:`J\\delta = -Q_1Q_1^T r`) with the part it cannot: :math:`c\\sqrt p` bounds
    the Gauss-Newton step in units of the estimate's own standard errors. It does not
    depend on how :math:`J` is scaled, so it refuses a point where the gradient vanishes
    only because the model flattens out (an asymptote: :math:`J \\to 0`, the residual
    still along :math:`J`). With no residual left to compare with (exact data, ``n == p``)
    the test is the **Gauss-Newton step** relative to the parameters,
    :math:`|\\delta_k| \\le` ``xtol`` :math:`|\\epsilon_k|` for every :math:`k` (a
    parameter at exactly zero: relative to the largest one). The step is computed on the
    columns of :math:`J` scaled to unit norm, so a parameter the model has become flat in
    (a rate gone to infinity) keeps its huge step and is refused; the offset test needs
    :math:`J` of full rank (scaled, to ``RANK_RCOND = 1e-10``). On bounds,
    parameters held at a bound by a gradient pointing out of the box (a
    Karush-Kuhn-Tucker multiplier of the right sign) are dropped from :math:`J` first
    (the projected problem).

General objectives (:func:`gradient_optimality`)
    The **Newton decrement** :math:`\\tfrac12 g^TH^{-1}g` (the decrease a Newton step
    would still make) against ``tol`` relative to :math:`\\max(|z|, 1)`, only when
    :math:`H` is positive definite: an indefinite or singular Hessian is not a minimum.

Constrained objectives, :math:`\\min f(z)` s.t. :math:`h(z) = 0`, :math:`c(z) \\ge 0`
(:func:`kkt_optimality`: the all-at-once SLSQP fits)
    The Karush-Kuhn-Tucker conditions, measured without units. **Feasibility**: the
    least-norm correction :math:`\\delta` with :math:`h'(z)\\delta = h(z)`, relative to
    :math:`\\|z\\|`, and the violation of the (scaled) inequalities, both at most
    ``FEASIBILITY_TOL = 1e-8``. **Stationarity**: multipliers :math:`y` (free) and
    :math:`\\mu \\ge 0` (active inequalities, :math:`c_i \\le 10^{-6}`) fitted by bounded
    linear least squares to :math:`\nabla f = h'^Ty + c_A'^T\\mu`; the remainder
    :math:`\rho` weighted by each variable's magnitude, :math:`\\max_i |\rho_i|\\,|z_i|
    / |f|`, is the relative change of the objective a relative change of one variable
    could still make, at most ``KKT_TOL = 1e-4`` (first order: the decrease a step
    would actually make is of second order, far smaller). Measured: SLSQP's "success"
    points 1e-7 to 1e-6 on the KPP study's fits and 1.8e-5 on a 3-sensor rod whose
    estimate equals the reduced fit's to 1e-8; its iteration-limit points 1e-2 to 3.

Defaults (documented floors): relative offset ``OFFSET_TOL = 1e-6`` (Bates and Watts suggest
1e-3 for statistical purposes; the Gauss-Newton step is then below :math:`10^{-6}\\sqrt p`
standard errors), Gauss-Newton step ``XTOL = 1e-8`` relative (the default ``xtol`` of
``scipy.optimize.least_squares``; a model solved by Newton to 1e-10 puts round-off of about
that size into the parameters of an exact-data fit).

References: Bates, D. M. and Watts, D. G. (1981), A relative offset orthogonality
convergence criterion for nonlinear least squares, Technometrics 23, 179-183.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.optimize
from scipy.linalg import lapack

from ..._validation import all_finite
from ...errors import ConvergenceError
from .status import FitStatus

_FLOAT64 = np.dtype(np.float64)
#: LAPACK's divide-and-conquer SVD (what np.linalg.svd runs), double precision
_gesdd, _gesdd_lwork = lapack.dgesdd, lapack.dgesdd_lwork
#: gesdd's optimal workspace by shape (a handful of shapes per session)
_gesdd_work = {}

__all__ = [
    "OFFSET_TOL",
    "XTOL",
    "Optimality",
    "decide_status",
    "minimize_optimality",
    "gradient_optimality",
    "kkt_optimality",
    "least_squares_optimality",
    "bounds_arrays",
    "polish_least_squares",
    "scaled_gradient_optimality",
    "scaled_svd",
]

#: a parameter within this fraction of its box's width of a bound is at it (the verdict's
#: identifiability finding; the KKT active set uses 1e-10)
AT_BOUND_RTOL = 1e-8
#: relative-offset tolerance of the least-squares test
OFFSET_TOL = 1e-6
_EPS = float(np.finfo(float).eps)
#: Gauss-Newton step tolerance, relative to the parameters (exact-fit problems)
XTOL = 1e-8
#: a Jacobian whose columns, scaled to unit norm, have smallest/largest singular value
#: below this is rank-deficient: no point estimate there
RANK_RCOND = 1e-10
#: Newton-decrement tolerance of the general test (relative to max(|z|, 1))
DECREMENT_TOL = 1e-10
#: gradient of a negative log-likelihood in the parameters' standard-error units: below
#: this the estimate is within that fraction of a standard error of the optimum
SCALED_GRADIENT_TOL = 1e-3
#: KKT stationarity tolerance of the constrained (all-at-once) fits: the first-order
#: change of the objective, relative to the objective, that a relative change of one
#: variable could still make along the constraints
KKT_TOL = 1e-4
#: feasibility tolerance of the constrained fits: the least-norm correction that would
#: satisfy the linearized equalities, relative to the variables; the scaled inequalities'
#: violation
FEASIBILITY_TOL = 1e-8


@dataclass(frozen=True)
class Optimality:
    """The verdict of an optimality test at one point.

    Attributes
    ----------
    converged : bool
    value : float
        The measured optimality (relative offset, relative Gauss-Newton step, or Newton
        decrement; ``inf`` when it cannot be measured).
    test : str
        Which test decided (``"relative offset"``, ``"gauss-newton step"``,
        ``"newton decrement"``, ``"kkt"``).
    tol : float
    message : str
        One sentence for the result's message.
    """

    converged: bool
    value: float
    test: str
    tol: float
    message: str
    #: the least-squares test's Gauss-Newton step, relative to the parameters (the
    #: distance to the optimum to first order; ``nan`` for the other tests)
    step: float = math.nan


def at_bound(eps, bounds, rtol=AT_BOUND_RTOL):
    """The parameters at a bound, as ``(index, "lower" | "upper")`` pairs: the one test of
    position (within ``rtol`` of the box's width, or of the parameter's size when a side
    is open), used by the verdict's identifiability finding and by the KKT active set."""
    if bounds is None:
        return []
    hits = []
    for m, (x, b) in enumerate(zip(eps, bounds, strict=False)):
        lo, hi = (None, None) if b is None else b
        lo = None if lo is None or not np.isfinite(lo) else lo
        hi = None if hi is None or not np.isfinite(hi) else hi
        if lo is not None and hi is not None:
            width = hi - lo
        else:
            width = max(abs(x), abs(lo or 0.0), abs(hi or 0.0), 1e-300)
        tol = rtol * max(abs(width), 1e-300)
        if lo is not None and x <= lo + tol:
            hits.append((m, "lower"))
        elif hi is not None and x >= hi - tol:
            hits.append((m, "upper"))
    return hits


def active_bounds(eps, g, bounds, rtol=1e-10):
    """Parameters held at a bound (:func:`at_bound`) by the gradient ``g`` pointing out of
    the box there (a KKT multiplier of the right sign), as a boolean mask."""
    active = np.zeros(np.size(eps), dtype=bool)
    for k, side in at_bound(eps, bounds, rtol):
        active[k] = g[k] >= 0 if side == "lower" else g[k] <= 0
    return active


def least_squares_optimality(r, J, eps, *, bounds=None, tol=OFFSET_TOL, xtol=XTOL):
    """Whether ``eps`` minimizes :math:`\\tfrac12\\|r\\|^2` (relative offset / GN step).

    Parameters
    ----------
    r : (n,) ndarray
        Residuals at ``eps``.
    J : (n, p) ndarray
        Their Jacobian :math:`\\partial r/\\partial\\epsilon`.
    eps : (p,) ndarray
    bounds : list of (lo, hi) or None
    tol : float
        Relative-offset tolerance.
    xtol : float
        Relative Gauss-Newton step tolerance.

    Returns
    -------
    Optimality
    """
    if not (type(r) is np.ndarray and r.dtype is _FLOAT64 and r.ndim == 1):
        r = np.asarray(r, dtype=float).ravel()
    if not (type(J) is np.ndarray and J.dtype is _FLOAT64 and J.shape[0] == r.size):
        J = np.asarray(J, dtype=float).reshape(r.size, -1)
    if not (type(eps) is np.ndarray and eps.dtype is _FLOAT64 and eps.ndim == 1):
        eps = np.asarray(eps, dtype=float).ravel()
    if not (all_finite(r) and all_finite(J)):
        return Optimality(False, np.inf, "relative offset", tol, "non-finite residual or Jacobian")
    if bounds is None:  # every parameter free
        free, Jf = slice(None), J
    else:
        free = ~active_bounds(eps, J.T @ r, bounds)
        if not free.any():
            return Optimality(True, 0.0, "kkt", tol, "every parameter held at a bound (KKT)")
        Jf = J[:, free]
    n, p = Jf.shape
    # one SVD of the columns scaled to unit norm (parameters' units do not matter) gives
    # all three: the rank, the orthonormal basis of the column space for the offset (the
    # offset needs a full-rank J: its basis would hold arbitrary directions otherwise) and
    # the minimum-norm Gauss-Newton step on the scaled columns, so a column of tiny norm (a
    # rate gone to infinity, the model flat in it) still counts, and only exactly parallel
    # columns (a combination the data cannot see) are left out
    norms, U, sv, Vt = scaled_svd(Jf)
    if U is not None:
        smallest, largest = float(sv[-1]), float(sv[0])
        rank_ok = smallest > RANK_RCOND * largest
        ur = U.T @ r
        if smallest > _EPS * max(n, p) * largest:  # lstsq's default cut-off: none cut
            delta = -(Vt.T @ (ur / sv)) / norms
        else:
            keep = sv > _EPS * max(n, p) * largest
            delta = -(Vt[keep].T @ (ur[keep] / sv[keep])) / norms
        orth = r - U @ ur
        # np.linalg.norm of a vector is sqrt(x.x): the same bits without its wrapper
        norm_orth = math.sqrt(orth.dot(orth))
        norm_proj = math.sqrt(ur.dot(ur))
    else:
        rank_ok = False
        delta = np.full(p, np.inf)
        norm_orth = norm_proj = 0.0  # no offset: the step test decides
    if n > p and norm_orth > 0:
        # math.sqrt: the correctly rounded root, as np.sqrt's
        offset = (norm_proj / math.sqrt(p)) / (norm_orth / math.sqrt(n - p))
    elif np.linalg.norm(r) == 0:
        offset = 0.0
    else:
        offset = np.inf  # nothing to compare with: the step test decides
    offset = float(offset)
    # relative to each parameter (a parameter at exactly 0: to the largest, else 1)
    if p <= 16 and bounds is None:
        # a few parameters: Python floats (the same IEEE quotients and maximum as numpy's,
        # without four array operations)
        ref = [abs(e) for e in eps.tolist()]
        if 0.0 in ref:
            big = max(ref) or 1.0
            ref = [e or big for e in ref]
        step = max(abs(d) / e for d, e in zip(delta.tolist(), ref, strict=True))
    else:
        ref = np.abs(eps[free])
        if not ref.all():
            ref[ref == 0] = np.abs(eps).max() or 1.0
        step = float((np.abs(delta) / ref).max())  # the method: np.max without its wrapper
    if offset <= tol and rank_ok:
        return Optimality(True, offset, "relative offset", tol,
                          f"relative offset {offset:.1e} <= {tol:.0e}", step)  # fmt: skip
    if step <= xtol:
        # on exactly parallel (scaled) columns this is a point of a whole set of optima:
        # first-order optimal, not unique; the uncertainty names the free combination
        note = "" if rank_ok else " (the Jacobian is rank-deficient: not a unique optimum)"
        return Optimality(True, step, "gauss-newton step", xtol,
                          f"Gauss-Newton step {step:.1e} <= {xtol:.0e} relative{note}", step)  # fmt: skip
    if np.isfinite(offset):
        value, test, t = offset, "relative offset", tol
        msg = (
            f"relative offset {offset:.1e} > {tol:.0e} and Gauss-Newton step {step:.1e} > "
            f"{xtol:.0e} relative: not at a least-squares optimum"
        )
    else:
        value, test, t = step, "gauss-newton step", xtol
        msg = f"Gauss-Newton step {step:.1e} > {xtol:.0e} relative: not at the optimum"
    if not rank_ok:
        msg += (
            " (the Jacobian is rank-deficient there: some parameter combination has no "
            "effect on the residuals, e.g. a rate gone to infinity)"
        )
    elif step > 1e3:
        msg += (
            " (the Gauss-Newton step is over 1000 times the parameters: the minimum may lie at "
            "infinity, where the model flattens out)"
        )
    return Optimality(False, value, test, t, msg, step)


#: the last scaled SVD, ``(key, value)`` in one slot (replaced whole: thread-safe)
_last_svd = [(None, None)]
#: Jacobians up to this many entries are remembered (a copy of their bytes is the key;
#: a larger one is factorized each time, not held in memory)
_SVD_KEEP_MAX = 100_000


def _thin_svd(A):
    """``np.linalg.svd(A, full_matrices=False)`` by LAPACK's gesdd through scipy's public
    wrapper (numpy's runs the same routine behind a heavier wrapper: several times the
    cost for a small least-squares Jacobian); numpy's where gesdd reports a failure (it
    raises LinAlgError, as before)."""
    m, n = A.shape
    lwork = _gesdd_work.get((m, n))
    if lwork is None:  # the optimal workspace, as numpy asks for it (the same path)
        lwork = _gesdd_work[m, n] = int(_gesdd_lwork(m, n, compute_uv=1, full_matrices=0)[0])
    U, sv, Vt, info = _gesdd(A, compute_uv=1, full_matrices=0, lwork=lwork)
    if info != 0:
        return np.linalg.svd(A, full_matrices=False)
    # numpy's layout (LAPACK writes column-major): products with U and Vt then run the
    # same BLAS kernels, so every later bit is as before
    return np.ascontiguousarray(U), sv, np.ascontiguousarray(Vt)


def scaled_svd(J):
    """The thin SVD of ``J`` with its columns scaled to unit norm: ``(norms, U, sv, Vt)``
    with ``J / norms = U diag(sv) Vt`` (``U = sv = Vt = None`` when a column is zero).

    The one factorization of a least-squares Jacobian that both the status test
    (:func:`least_squares_optimality`) and the Gauss-Newton uncertainty
    (:func:`~ecfm_uq.inverse.statistics.uncertainty.least_squares_jacobian`) need: the
    last one is kept (up to ``_SVD_KEEP_MAX`` entries), keyed by ``J``'s shape and bytes,
    so the second asks for it at the cost of a comparison (same bits in, same bits out).
    The returned arrays are shared and read-only.
    """
    J = np.asarray(J, dtype=float)
    key = (J.shape, J.tobytes()) if J.size <= _SVD_KEEP_MAX else None
    last_key, last_value = _last_svd[0]
    if key is not None and last_key == key:
        return last_value
    with np.errstate(over="ignore"):  # squares beyond 1e308: the scaled sums below
        norms = np.sqrt(np.add.reduce(J * J, axis=0))  # np.linalg.norm(J, axis=0)'s bits
    if not all_finite(norms) and all_finite(J):
        big = np.abs(J).max(axis=0)
        norms = big * np.sqrt(np.add.reduce((J / np.where(big > 0, big, 1.0)) ** 2, axis=0))
    if (norms > 0).all():
        U, sv, Vt = _thin_svd(J / norms)
    else:
        U = sv = Vt = None
    value = (norms, U, sv, Vt)
    for a in value:
        if a is not None:
            a.flags.writeable = False
    if key is not None:
        _last_svd[0] = (key, value)
    return value


def gradient_optimality(z, g, H, *, x=None, bounds=None, tol=DECREMENT_TOL):
    """Whether a point with gradient ``g`` and Hessian ``H`` minimizes a general ``z``.

    The Newton decrement :math:`\\tfrac12 g^TH^{-1}g \\le` ``tol`` :math:`\\max(|z|, 1)`
    with :math:`H` positive definite. With ``x`` and ``bounds``, the components held at a
    bound by a gradient pointing out of the box (a KKT multiplier of the right sign) are
    dropped first: the test is that of the problem projected on the free parameters, and
    an estimate with every parameter held at a bound is optimal (an identifiability
    finding for the verdict, not a convergence failure).

    Returns
    -------
    Optimality
    """
    g = np.asarray(g, dtype=float).ravel()
    if x is not None and bounds is not None:
        free = ~active_bounds(np.asarray(x, dtype=float).ravel(), g, bounds)
        H = np.asarray(H, dtype=float).reshape(g.size, g.size)[np.ix_(free, free)]
        g = g[free]
        if g.size == 0:
            return Optimality(True, 0.0, "newton decrement", tol,
                              "every parameter is held at a bound by the gradient")  # fmt: skip
    H = np.asarray(H, dtype=float).reshape(g.size, g.size)
    if not (np.isfinite(z) and np.all(np.isfinite(g)) and np.all(np.isfinite(H))):
        return Optimality(False, np.inf, "newton decrement", tol, "non-finite objective")
    H = 0.5 * (H + H.T)
    w = np.linalg.eigvalsh(H)
    if w[0] <= 1e-12 * max(abs(w[-1]), 1e-300):
        return Optimality(False, np.inf, "newton decrement", tol,
                          f"the Hessian is not positive definite (eigenvalues {w[0]:.2e}, "
                          f"{w[-1]:.2e}): not a minimum")  # fmt: skip
    dec = 0.5 * float(g @ np.linalg.solve(H, g)) / max(abs(z), 1.0)
    ok = dec <= tol
    rel = "<=" if ok else ">"
    return Optimality(ok, dec, "newton decrement", tol,
                      f"relative Newton decrement {dec:.1e} {rel} {tol:.0e}")  # fmt: skip


def kkt_optimality(z, f, g, h, H, c=None, C=None, *, f_scale=0.0, f_lower=None,
                   tol=KKT_TOL, feasibility_tol=FEASIBILITY_TOL, active_tol=1e-6):  # fmt: skip
    """Whether ``z`` is a KKT point of :math:`\\min f` s.t. :math:`h = 0`, :math:`c \\ge 0`.

    Parameters
    ----------
    z : (n,) ndarray
        The point.
    f : float
        Objective at ``z``.
    g : (n,) ndarray
        Its gradient.
    h, H : (m,) and (m, n) ndarray
        Equality constraints and their Jacobian.
    c, C : (k,) and (k, n) ndarray, optional
        Inequality constraints, scaled to order one, and their Jacobian.
    f_scale : float
        A magnitude of the objective (e.g. the largest value seen along the iterates):
        an objective below 1e-12 of it counts as zero.
    f_lower : float, optional
        A lower bound of the objective (0 for a sum of squares): a feasible point whose
        objective is there (to 1e-12 of ``f_scale``) is optimal.

    Returns
    -------
    Optimality
        ``test == "kkt"``, ``value`` the stationarity measure (``inf`` when infeasible or
        not finite).
    """
    z = np.asarray(z, dtype=float).ravel()
    g = np.asarray(g, dtype=float).ravel()
    H = np.asarray(H, dtype=float).reshape(-1, z.size)
    h = np.asarray(h, dtype=float).ravel()
    c = np.zeros(0) if c is None else np.asarray(c, dtype=float).ravel()
    C = np.zeros((0, z.size)) if C is None else np.asarray(C, dtype=float).reshape(-1, z.size)
    arrays = (z, g, h, H, c, C)
    if not (np.isfinite(f) and all(np.all(np.isfinite(a)) for a in arrays)):
        return Optimality(False, np.inf, "kkt", tol, "non-finite point or derivatives")
    size = max(float(np.linalg.norm(z)), 1e-300)
    correction = np.linalg.lstsq(H, h, rcond=None)[0] if h.size else np.zeros(0)
    infeasible = float(np.linalg.norm(correction)) / size
    violated = float(max(-c.min(), 0.0)) if c.size else 0.0
    if infeasible > feasibility_tol or violated > feasibility_tol:
        return Optimality(False, np.inf, "kkt", tol,
                          f"infeasible: equality correction {infeasible:.1e} of |z|, "
                          f"inequality violation {violated:.1e} (> {feasibility_tol:.0e})")  # fmt: skip
    floor = 1e-12 * max(abs(float(f_scale)), abs(float(f)))
    if f_lower is not None and float(f) - f_lower <= floor:
        return Optimality(True, 0.0, "kkt", tol,
                          f"feasible, objective at its lower bound {f_lower:g}")  # fmt: skip
    active = c <= active_tol
    A = np.vstack([H, C[active]])
    lower = np.concatenate([np.full(h.size, -np.inf), np.zeros(int(active.sum()))])
    if A.shape[0]:
        mult = scipy.optimize.lsq_linear(A.T, g, bounds=(lower, np.inf)).x
        rho = g - A.T @ mult
    else:
        rho = g
    weight = np.maximum(np.abs(z), 1e-3 * float(np.max(np.abs(z), initial=0.0)))
    denominator = max(abs(float(f)), floor, 1e-300)
    value = float(np.max(np.abs(rho) * weight, initial=0.0)) / denominator
    ok = value <= tol
    rel = "<=" if ok else ">"
    return Optimality(ok, value, "kkt",  tol,
                      f"KKT stationarity {value:.1e} {rel} {tol:.0e} "
                      f"({int(active.sum())} active inequalities)")  # fmt: skip


def scaled_gradient_optimality(g, x=None, bounds=None, *, tol=SCALED_GRADIENT_TOL):
    """Whether a negative log-likelihood's gradient vanishes in standard-error units.

    ``g`` is the gradient with respect to parameters scaled by their standard errors
    (:math:`\\epsilon = \\hat\\epsilon_0 + s \\odot x`): a log-likelihood is unit-free and
    so is ``x``, so :math:`\\max_k |g_k| \\le` ``tol`` leaves the estimate within about
    ``tol`` standard errors of the optimum whatever the units. Components held at a bound
    of ``bounds`` (in ``x``) by a gradient pointing out of the box are dropped (KKT).

    Returns
    -------
    Optimality
        ``test == "scaled gradient"``.
    """
    g = np.asarray(g, dtype=float).ravel()
    if not np.all(np.isfinite(g)):
        return Optimality(False, np.inf, "scaled gradient", tol, "non-finite gradient")
    if x is not None and bounds is not None:
        g = g[~active_bounds(np.asarray(x, dtype=float).ravel(), g, bounds)]
    value = float(np.max(np.abs(g), initial=0.0))
    ok = value <= tol
    rel = "<=" if ok else ">"
    return Optimality(ok, value, "scaled gradient", tol,
                      f"gradient {value:.1e} {rel} {tol:.0e} in standard-error units")  # fmt: skip


def minimize_optimality(g, x, z, scale, gtol, bounds, *, precise=True):
    r"""First-order optimality of :func:`~ecfm_uq.inverse.core.drivers.minimize_scaled`'s (or :func:`~ecfm_uq.inverse.core.optimizers.adam`'s) objective at its returned point.

    Converged when the gradient of the scaled objective :math:`z/z(\epsilon_0)`, the
    components at an active bound left out, is at most ``gtol`` (max norm); or, with
    ``precise`` (no inner solve failed), when ``z`` is at round-off zero (both objectives
    are >= 0: a global minimum) or when a relative change of ``eps`` would change ``z`` by
    less than 1e-6 relative (the round-off limit of misspecified data, :math:`z^* > 0`).

    Parameters
    ----------
    g : (n,) ndarray
        Gradient of ``z`` at ``x``.
    x : (n,) ndarray
    z : float
    scale : float
        :math:`z(\epsilon_0)` (1 when that is 0).
    gtol : float
    bounds : list of (lo, hi) or None
    precise : bool, optional

    Returns
    -------
    Optimality
        ``test`` is ``"relative gradient"``, ``"round-off zero"`` or ``"round-off limit"``.
    """
    g = np.asarray(g, dtype=float)
    if not np.all(np.isfinite(g)) or not np.isfinite(z):
        return Optimality(False, np.inf, "relative gradient", gtol, "non-finite gradient")
    free = g if bounds is None else g[~active_bounds(np.asarray(x, dtype=float), g, bounds)]
    value = float(np.max(np.abs(free), initial=0.0)) / scale
    if value <= gtol:
        return Optimality(True, value, "relative gradient", gtol,
                          f"relative gradient {value:.1e} <= {gtol:.0e}")  # fmt: skip
    rel_opt = float(np.linalg.norm(g) * max(np.linalg.norm(x), 1.0) / max(z, 1e-300))
    if precise and z <= 1e-20 * scale:
        return Optimality(True, rel_opt, "round-off zero", gtol,
                          "objective at round-off zero: global minimum")  # fmt: skip
    if precise and rel_opt <= 1e-6:
        return Optimality(True, rel_opt, "round-off limit", 1e-6,
                          f"stopped at the round-off limit; relative optimality {rel_opt:.1e}")  # fmt: skip
    return Optimality(False, value, "relative gradient", gtol,
                      f"relative gradient {value:.1e} > {gtol:.0e}")  # fmt: skip


def decide_status(opt, exhausted, failure=None):
    """The one status decision of every fit, from what was measured.

    Parameters
    ----------
    opt : Optimality or None
        The optimality conditions measured at the returned point (``None`` when they
        could not be measured: the model fails there).
    exhausted : bool
        Whether the optimizer's budget ran out.
    failure : Exception, str or None
        A model failure measured at the returned point (the model cannot be solved
        there), or ``None``.

    Returns
    -------
    FitStatus
        MODEL_FAILURE when ``failure`` is given (or nothing was measured), else CONVERGED
        when ``opt`` holds, else MAX_ITERATIONS when ``exhausted``, else STALLED.
    """
    if failure is not None or opt is None:
        return FitStatus.MODEL_FAILURE
    if opt.converged:
        return FitStatus.CONVERGED
    return FitStatus.MAX_ITERATIONS if exhausted else FitStatus.STALLED


def polish_least_squares(residual, eps, *, bounds=None, maxiter=20, tol=OFFSET_TOL, xtol=XTOL,
                         step_tol=math.inf, first=None):  # fmt: skip
    """A few Levenberg-Marquardt steps from ``eps`` until :func:`least_squares_optimality`
    holds and its Gauss-Newton step is at most ``step_tol`` relative to the parameters (or
    they stop decreasing the sum of squares).

    Parameters
    ----------
    residual : callable
        ``eps -> (r (n,), J (n, p), payload)``; may raise
        :class:`~ecfm_uq.errors.ConvergenceError` (a rejected step).
    eps : (p,) ndarray
    bounds : list of (lo, hi) or None
        Steps are clipped into the box.
    maxiter : int
    step_tol : float
        Steps go on where the test holds but its Gauss-Newton step is larger than this
        (an estimate as accurate as the data's, not only statistically optimal).
    first : tuple, optional
        ``residual(eps)``, when the caller has it.

    Returns
    -------
    eps : (p,) ndarray
    evaluation : tuple
        ``(r, J, payload)`` at ``eps``.
    optimality : Optimality
    nfev : int
        Residual evaluations made.
    """
    x = np.asarray(eps, dtype=float).copy()
    lo, hi = bounds_arrays(bounds, x.size)
    ev, nfev = (residual(x), 1) if first is None else (first, 0)
    opt = least_squares_optimality(ev[0], ev[1], x, bounds=bounds, tol=tol, xtol=xtol)
    mu = 0.0  # a pure Gauss-Newton step first (quadratic convergence near the optimum)
    for _ in range(maxiter):
        if opt.converged and not opt.step > step_tol:
            break
        r, J = ev[0], ev[1]
        cost = float(r @ r)
        with np.errstate(over="ignore"):
            A = J.T @ J
        if not np.isfinite(A).all():  # a Jacobian too large to square: no LM step
            break
        d = np.sqrt(np.maximum(np.diag(A), 1e-300 * max(np.diag(A).max(), 1e-300)))
        improved = False
        for _ in range(12):
            # (J^T J + mu D^2) step = -g, via the augmented least-squares system
            Aug = np.vstack([J, np.sqrt(mu) * np.diag(d)])
            step = np.linalg.lstsq(Aug, -np.concatenate([r, np.zeros(x.size)]), rcond=None)[0]
            xt = np.clip(x + step, lo, hi)
            if np.array_equal(xt, x):
                break
            try:
                et = residual(xt)
                nfev += 1
            except ConvergenceError:
                nfev += 1
                mu = max(mu * 10.0, 1e-6)
                continue
            ok = np.all(np.isfinite(et[0])) and np.all(np.isfinite(et[1]))
            cost_t = float(et[0] @ et[0]) if ok else np.inf
            better = cost_t < cost
            if ok and not better and cost_t <= cost * (1 + 1e-9):
                # a change of the sum of squares below its round-off: judge the step by
                # the optimality it reaches (Q1^T r is computed accurately there)
                opt_t = least_squares_optimality(et[0], et[1], xt, bounds=bounds, tol=tol,
                                                 xtol=xtol)  # fmt: skip
                better = opt_t.value < opt.value
            if better:
                x, ev, improved = xt, et, True
                mu = mu / 10.0 if mu > 1e-9 else 0.0
                break
            mu = max(mu * 10.0, 1e-6)
        if not improved:
            break
        opt = least_squares_optimality(ev[0], ev[1], x, bounds=bounds, tol=tol, xtol=xtol)
    return x, ev, opt, nfev


def bounds_arrays(bounds, p):
    """``bounds`` (a list of (lo, hi), None for no bound, or None) as two (p,) arrays
    with infinities where there is no bound."""
    if bounds is None:
        return np.full(p, -np.inf), np.full(p, np.inf)
    lo = np.array([-np.inf if b[0] is None else b[0] for b in bounds], dtype=float)
    hi = np.array([np.inf if b[1] is None else b[1] for b in bounds], dtype=float)
    return lo, hi
