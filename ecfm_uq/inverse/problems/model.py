"""A model that is a Python function: :class:`ModelProblem`, and its least-squares fit.

The front door for a model without equations the library can see (a regression, an ODE
solved by the user, a wrapped simulator): ``model(eps)`` returns the predictions of the
data, with the data's shape. Its Jacobian is the user's ``jac(eps)``, or differenced
(:mod:`ecfm_uq.inverse.core.finite_differences`: one-sided, central or complex steps sized
to each parameter), its model runs optionally through an executor (a ``dask.distributed``
client for expensive models). :func:`~ecfm_uq.inverse.fit` runs the standard formulation on
it (least squares on the whitened residual :math:`W(f(\\epsilon) - v)`,
:mod:`ecfm_uq.inverse.problems.noise_model`: MINPACK's Levenberg-Marquardt without bounds,
trust-region reflective with them, then the status test on central differences where the
fit's are one-sided), and the result has everything a fit offers:
the status from the optimality conditions, Gauss-Newton standard errors, profile intervals,
likelihood-ratio tests, posterior samples and the verdict (a chi-squared test with
``sigma``; none without).

A model that raises, returns the wrong shape or a non-finite value is reported with the
parameters it was called at: at the starting point as an error (nothing was computed
yet), later as a rejected trial point (the optimizer backs off; the result keeps the best
point reached).
"""

from __future__ import annotations

import math

import numpy as np

from ..._validation import all_finite, as_finite_array, as_model_output
from ...errors import ConvergenceError, ModelEvaluationError
from ...executor import evaluate_samples
from ...threads import NO_DENSE
from ..core.details import ModelDetails
from ..core.drivers import least_squares_scaled
from ..core.finite_differences import fd_jacobian
from ..core.fitter import Fitter, Outcome, holds
from ..core.levenberg_marquardt import least_squares_lm
from ..core.result import Uncertainty
from ..core.settings import check_least_squares_options
from ..statistics.loglik import gaussian_likelihood, remember_last_point
from ..statistics.uncertainty import estimate_uncertainty, least_squares_jacobian
from ..statistics.verdict import check_bounds, model_verdict
from .interface import InverseProblem
from .noise_model import noise_model

_FLOAT64 = np.dtype(np.float64)

__all__ = ["ModelFitter", "ModelProblem", "fit_model_problem", "model_fit_fields"]

_JAC_MODES = ("2-point", "3-point", "cs")


def _describe_call(name, eps):
    return f"`{name}` {_at(eps)}"


def _at(eps):
    return f"at eps={np.array2string(np.asarray(eps).real, precision=6)}"


class ModelProblem(InverseProblem):
    """Data ``v`` and a model ``model(eps)`` that predicts them.

    Parameters
    ----------
    model : callable
        ``model(eps) -> array_like`` of real numbers with the shape of ``data`` (axes of
        length 1 aside: a flat vector for 2-D data is refused, its order would be a
        guess); ``eps`` is a 1-D float array of the parameters (complex for
        ``jac="cs"``, and the model must then be complex-analytic: checked once against
        central differences). Its output is copied, so it may reuse one array.
    data : array_like
        The observations, any shape (flattened in the fit, C order).
    jac : callable or {"2-point", "3-point", "cs"} or None
        ``jac(eps) -> (data.size, n_eps)`` (or ``data.shape + (n_eps,)``), the model's
        derivative; a string (or ``None``, meaning ``"2-point"``, scipy's default) for
        finite differences with steps sized to each parameter, central differences or
        complex steps (the model must then accept complex ``eps``).
    executor : object with ``map``, optional
        Evaluate the model points of one differenced Jacobian through it (e.g. a
        ``dask.distributed.Client`` or a ``concurrent.futures`` pool;
        :func:`ecfm_uq.executor.evaluate_samples`). Default: in this process.
    names : sequence of str, optional
        Parameter names for messages and :meth:`~ecfm_uq.inverse.InverseResult.summary`.

    Raises
    ------
    TypeError, ValueError
        ``model``/``jac`` not callable, an unknown ``jac`` mode, non-finite ``data``.
    """

    formulations = ("standard",)
    #: the dense systems the library factorizes for this problem: none of note (an
    #: n-by-p SVD), so a fit leaves the BLAS threads as the caller set them
    #: (:data:`ecfm_uq.threads.NO_DENSE`; the user's model keeps its own threads)
    dense_unknowns = NO_DENSE

    def __init__(self, model, data, *, jac=None, executor=None, names=None):
        if not callable(model):
            raise TypeError(f"`model` must be a callable model(eps) -> predictions, got {model!r}")
        if jac is None:
            jac = "2-point"
        if isinstance(jac, str):
            if jac not in _JAC_MODES:
                raise ValueError(
                    f"`jac` must be a callable jac(eps) or one of {_JAC_MODES} (finite "
                    f"differences), got {jac!r}"
                )
        elif not callable(jac):
            raise TypeError(f"`jac` must be a callable jac(eps) or a string, got {jac!r}")
        if executor is not None and not callable(getattr(executor, "map", None)):
            raise TypeError("`executor` must have a map method (a dask Client, a pool)")
        data = np.asarray(data, dtype=float) if not np.isscalar(data) else np.array([data])
        self.shape = data.shape
        self.v = as_finite_array("data", data.ravel())
        self._ones = np.ones(self.v.size)  # a finiteness test by one inner product
        self.model, self.jac, self.executor = model, jac, executor
        self.names = None if names is None else [str(n) for n in names]

    # -- evaluations ------------------------------------------------------------------------
    def predict(self, eps, *, first=False):
        """``model(eps)`` flattened and checked.

        Raises
        ------
        TypeError, ValueError
            At the first call (``first``): a model that raises, returns the wrong shape or
            non-finite values, with the parameters and the fix.
        ModelEvaluationError
            Later: the same, as a failed evaluation the optimizer backs off from.
        """
        y, own = self._output(eps, first)
        if not own:
            return y
        # the common output: one copy (a model may reuse its output array), one
        # finiteness test by an inner product (all_finite's, without its dispatch)
        y = y.copy().ravel()
        if math.isfinite(y.dot(self._ones)):
            return y
        return self._checked(y, eps, first)

    def _output(self, eps, first=False):
        """``(y, own)``: ``model(eps)``, the model's own array with its values unchecked
        when it is the common output (``own``), else :meth:`_checked`'s fresh one; a
        model that raises, reported with its call (see :meth:`predict`)."""
        try:
            y = self.model(eps)
        except Exception as e:  # a user callback: report any failure with its call
            raise self._model_error(e, eps, first) from e
        if type(y) is np.ndarray and y.dtype is _FLOAT64 and y.shape == self.shape:
            return y, True
        return self._checked(y, eps, first), False

    def _model_error(self, e, eps, first):
        """The error to raise for ``model(eps)`` raising ``e`` (see :meth:`predict`)."""
        msg = f"{_describe_call('model', eps)} raised {type(e).__name__}: {e}"
        if first or isinstance(e, TypeError | IndexError):
            return type(e)(
                f"{msg}; `model` must take one argument, the 1-D array of the "
                f"{np.size(eps)} parameters, and return the predictions of the data "
                f"(shape {self.shape})"
            )
        return ModelEvaluationError(msg)

    def _checked(self, y, eps, first):
        """``model(eps)``'s return ``y`` as a fresh flat float array, checked (see
        :meth:`predict`)."""
        cs = self.jac == "cs"  # a model for complex steps may hand back a complex array
        y = as_model_output(
            y, name="model", at=lambda: _at(eps), shape=self.shape, complex_ok=cs
        ).ravel()
        if cs and np.iscomplexobj(y):
            if np.any(y.imag != 0):
                raise TypeError(
                    f"{_describe_call('model', eps)} returned complex values for real "
                    "parameters; `model` must return real predictions at real eps"
                )
            y = y.real.copy()
        if not all_finite(y):
            bad = np.flatnonzero(~np.isfinite(y))
            msg = (
                f"{_describe_call('model', eps)} returned {bad.size} non-finite value(s) "
                f"(first at index {int(bad[0])}: {y[bad[0]]})"
            )
            if first:
                raise ValueError(f"{msg}; start from parameters where the model is defined")
            raise ModelEvaluationError(msg)
        return y

    def jacobian(self, eps, y=None, *, columns=None, typical=None, method=None):
        """:math:`\\partial f/\\partial\\epsilon` at ``eps``, (n_data, n_eps) (or the
        requested ``columns``), from ``jac`` or by finite differences (``method``, default
        the problem's ``jac`` mode, overrides a differencing mode)."""
        eps = np.asarray(eps, dtype=float)
        if callable(self.jac):
            J = self._user_jacobian(eps)
            return J if columns is None else J[:, columns]
        if self.jac == "cs":
            fun = self._complex_model
            J = fd_jacobian(fun, eps, method="cs", typical=typical, columns=columns)
            if columns is None and not getattr(self, "_analytic", False):
                self._check_analytic(eps, J, typical)
            return J
        method = method or self.jac
        if method == "3-point" and self.executor is None:
            # the stencil's outputs unchecked one by one: the Jacobian is tested whole
            # (finite differences of finite outputs), predict's checks then raise
            J = fd_jacobian(self._stencil_point, eps, method=method, typical=typical,
                            columns=columns)  # fmt: skip
            if all_finite(J):
                return J
        return fd_jacobian(
            self.predict, eps, method=method, typical=typical, f0=y, columns=columns,
            map_points=None if self.executor is None else self._map,
        )  # fmt: skip

    def _stencil_point(self, eps):
        """``model(eps)`` at a central-difference stencil's point (:meth:`_output`: the
        stencil copies what it keeps and tests the Jacobian whole)."""
        return self._output(eps)[0]

    def _complex_model(self, z):
        try:
            out = self.model(z)
        except Exception as e:
            raise ModelEvaluationError(
                f"{_describe_call('model', z)} with a complex step raised "
                f"{type(e).__name__}: {e}; jac='cs' needs a model written for complex "
                "parameters (no abs, no comparisons, no float()); use jac='3-point'"
            ) from e
        y = as_model_output(out, name="model", at=lambda: _at(z), complex_ok=True)
        if not np.iscomplexobj(y):
            raise ValueError(
                "jac='cs': `model` dropped the imaginary part of complex parameters (it "
                "returned real values); use jac='3-point' or '2-point'"
            )
        return y.ravel()

    def _check_analytic(self, eps, J, typical):
        """Once, at the first complex-step Jacobian: central differences must agree with
        it, else the model is not complex-analytic (``abs``, ``.real``, a comparison) and
        its complex steps are wrong, not its Jacobian rank-deficient."""
        F = fd_jacobian(self.predict, eps, method="3-point", typical=typical)
        # columns as responses to relative changes of the parameters, so that a column
        # near zero is judged against the others (differencing noise is not a mismatch)
        w = np.maximum(np.abs(eps), 1.0 if typical is None else np.abs(typical))
        w = np.where(w > 0, w, 1.0)
        scale = np.maximum(np.abs(F).max(axis=0), np.abs(J).max(axis=0)) * w
        floor = max(1e-6 * scale.max(), np.finfo(float).tiny)
        err = np.abs(J - F).max(axis=0) * w / np.maximum(scale, floor)
        if err.max() > 1e-3:
            j = int(np.argmax(err))
            raise ValueError(
                f"jac='cs': the complex-step derivative in parameter {j} differs from central "
                f"differences by {err[j]:.2g} (relative) {_at(eps)}: `model` is not "
                "complex-analytic in it (abs, np.real, comparisons, max/min, float() drop "
                "the imaginary step); use jac='3-point', or write the model with analytic "
                "operations only"
            )
        self._analytic = True

    def _user_jacobian(self, eps):
        p = eps.size
        try:
            out = self.jac(eps)
        except Exception as e:
            raise type(e)(
                f"{_describe_call('jac', eps)} raised {type(e).__name__}: {e}; `jac` must "
                f"take the 1-D array of the {p} parameters and return the "
                f"({self.v.size}, {p}) derivative of the predictions"
            ) from e
        J = as_model_output(out, name="jac", at=lambda: _at(eps))
        if J.shape not in ((self.v.size, p), (*self.shape, p)):
            raise ValueError(
                f"{_describe_call('jac', eps)} returned shape {J.shape}; expected "
                f"({self.v.size}, {p}): one row per observation, one column per parameter"
            )
        J = J.reshape(self.v.size, p)
        if not np.all(np.isfinite(J)):
            raise ModelEvaluationError(f"{_describe_call('jac', eps)} returned non-finite values")
        return J

    def _map(self, points):
        return evaluate_samples(self.model, points, self.executor, name="model")

    def residual_function(self, noise, *, typical=None, accurate=False):
        """``eps -> (r, J, y)``: whitened residual :math:`W(f(\\epsilon) - v)`, its
        Jacobian as a callable (computed when asked for) and the predictions.

        The function's ``jacobian_at(eps, y)`` is the Jacobian alone, at a point whose
        predictions ``y`` are known (the status test at a driver's last point); its
        ``jacobian_evaluations`` the model evaluations one Jacobian costs (the stencil's
        points; none for a given ``jac``), which the drivers count into ``nfev``.

        ``accurate``: one-sided differences (``jac="2-point"``) are replaced by central
        ones (error :math:`O(\\varepsilon^{2/3})` instead of :math:`O(\\varepsilon^{1/2})`
        relative): the Jacobian of the status test and of the final Gauss-Newton steps,
        whose stationary point is then the optimum's to that accuracy, not to the
        one-sided differences' (which shift it by :math:`(J^TJ)^{-1}\\Delta J^Tr`).
        """
        v = self.v
        # the central-difference residual runs after the fit's: its first call is no
        # longer the start, where a failing model is the user's error
        first = not accurate
        method = "3-point" if accurate and self.jac == "2-point" else None

        whiten = noise.whiten if noise.known else None  # unknown sigma: W = I
        model, shape, checked = self.model, self.shape, self._checked
        ones = self._ones
        flat = len(shape) == 1

        def values(eps, at_start=False, square=True):
            """``(r, ss, y, fresh)``: the whitened residual, its sum of squares when
            ``square`` (else ``None``), the predictions and whether ``y`` is a new array
            (else the model's own, which a caller copies before keeping it); predict's
            checks, the finiteness test by one inner product (the sum of squares when
            asked for: its overflow is then the caller's to silence). Its defaults are
            ``plain``'s."""
            try:
                y = model(eps)
            except Exception as e:  # a user callback: report any failure with its call
                raise self._model_error(e, eps, at_start) from e
            if type(y) is np.ndarray and y.dtype is _FLOAT64 and y.shape == shape:
                if not flat:
                    y = y.ravel()
                r = y - v
                if whiten is not None:
                    r = whiten(r)
                ss = r.dot(r) if square else None
                # r finite iff y is (v is): its sum (or squares) say so; a bad value raises
                if not math.isfinite(r.dot(ones) if ss is None else ss):
                    checked(y, eps, at_start)
                return r, ss, y, False
            y = checked(y, eps, at_start)
            r = y - v
            if whiten is not None:
                r = whiten(r)
            return r, (r.dot(r) if square else None), y, True

        def residual(eps):
            nonlocal first
            # the first call (at eps0) raises the user's errors: nothing was computed yet
            at_start, first = first, False
            r, _, y, fresh = values(eps, at_start, False)
            if not fresh:
                y = y.copy()

            def J():
                return noise.whiten(self.jacobian(eps, y, typical=typical, method=method))

            return r, J, y

        def jacobian_at(eps, y):
            """The Jacobian ``residual(eps)[1]()`` of a point whose predictions ``y``
            are known (no model evaluation at ``eps`` itself)."""
            return noise.whiten(self.jacobian(eps, y, typical=typical, method=method))

        residual.jacobian_at = jacobian_at
        # ``(r, r @ r, y, fresh)`` at a point after the first, for MINPACK's
        # differencing: no Jacobian closure (the driver silences the squares' overflow)
        residual.plain = values
        mode = method or self.jac
        residual.jacobian_evaluations = (
            0 if callable(mode) or typical is None else _STENCIL_POINTS[mode] * len(typical)
        )
        return residual

    def check_derivatives(self, eps, *, rtol=1e-4):
        """Compare the user's ``jac`` with central differences of ``model`` at ``eps``.

        Returns
        -------
        float
            The largest difference relative to the largest entry of each column.

        Raises
        ------
        ValueError
            When the difference exceeds ``rtol``, naming the worst column.
        """
        if not callable(self.jac):
            raise ValueError("`jac` is differenced already: there is no derivative to check")
        eps = as_finite_array("eps", eps, ndim=1)
        J = self._user_jacobian(eps)
        F = fd_jacobian(lambda e: self.predict(e, first=True), eps, method="5-point")
        scale = np.maximum(np.max(np.abs(F), axis=0), np.max(np.abs(J), axis=0))
        err = np.max(np.abs(J - F), axis=0) / np.where(scale > 0, scale, 1.0)
        worst = int(np.argmax(err))
        if err[worst] > rtol:
            raise ValueError(
                f"`jac` disagrees with finite differences of `model` in column {worst} "
                f"(relative difference {err[worst]:.2e} > rtol={rtol:g}) at eps="
                f"{eps.tolist()}: check its sign and its column order"
            )
        return float(err[worst])


#: model evaluations per parameter of a Jacobian by each difference mode
_STENCIL_POINTS = {"2-point": 1, "3-point": 2, "5-point": 4, "cs": 1}


def _stalled(out):
    """Whether a driver stopped on its own short of an optimum: the conditions measured
    not to hold at a point where the model can be solved, the budget not run out."""
    return (
        out.final_error is None and out.opt is not None and not (out.opt.converged or out.exhausted)
    )


class ModelFitter(Fitter):
    """``ModelProblem``, ``"standard"``: least squares of the model function
    (:func:`fit_model_problem`)."""

    kind, formulation, default_method = "model", "standard", "least-squares"

    def run(self, problem, eps0, settings):
        return fit_model_problem(problem, eps0, settings)


def fit_model_problem(problem, eps0, s):
    """:func:`~ecfm_uq.inverse.fit` for a :class:`ModelProblem` (validated settings ``s``):
    the :class:`~ecfm_uq.inverse.core.fitter.Outcome` (the optimality measured by the
    drivers; ``fit`` decides the status)."""
    return Outcome(**model_fit_fields(problem, eps0, s))


def model_fit_fields(problem, eps0, s):
    """The fields of :func:`fit_model_problem`'s
    :class:`~ecfm_uq.inverse.core.fitter.Outcome`, as a dict (a fitter that adds its own,
    :func:`~ecfm_uq.inverse.problems.ode.fit_ode_standard`, builds the outcome once)."""
    if s.formulation not in problem.formulations:
        raise ValueError(
            f"formulation={s.formulation!r} needs the model's equations (constraint forces "
            "enter them); a ModelProblem is a function: use formulation='standard', or "
            "build a SteadyProblem/DynamicInverseProblem for ECFM"
        )
    if s.method not in ("auto", "least-squares", "trf", "lm"):
        raise ValueError(
            f"unknown `method` {s.method!r} for a ModelProblem; choose 'least-squares' (the "
            "default: Levenberg-Marquardt without bounds, trust-region reflective with "
            "them), 'lm' or 'trf'"
        )
    # the trust region runs to round-off (scipy's 1e-8 stops ENSO and MGH09 at 1e-6 of
    # NIST's values), LM to its own LM_FTOL; whether the end is an optimum is the
    # relative-offset test's say
    options = s.take({"polish": True, "x_scale": "jac", "ftol": 1e-15, "xtol": 1e-15,
                      "gtol": 1e-15})  # fmt: skip
    eps0 = as_finite_array("eps0", eps0, ndim=1)
    p, n = eps0.size, problem.v.size
    bounds = check_bounds(s.bounds, p)
    options = check_least_squares_options(options, p)
    if "ftol" not in s.options:
        del options["ftol"]  # each driver's own round-off level (drivers.LM_FTOL for LM)
    if n < p:
        raise ValueError(
            f"`data` has {n} observations for {p} parameters: fewer data than parameters "
            "cannot determine eps"
        )
    if problem.names is not None and len(problem.names) != p:
        raise ValueError(f"`names` has {len(problem.names)} entries for {p} parameters")
    lm = (
        s.method != "trf"
        and bounds is None
        and isinstance(options["x_scale"], str)
        and (options["x_scale"] == "jac")
    )
    if s.method == "lm" and not lm:
        raise ValueError(
            "method='lm' (Levenberg-Marquardt) takes no `bounds` and only x_scale='jac'; "
            "use method='trf' for a bounded fit"
        )
    noise = noise_model(s.sigma, n)
    # the driver keeps its own last point; the likelihood (profiles, tests) remembers one
    raw = problem.residual_function(noise, typical=eps0)
    residual = remember_last_point(raw)
    # the status test and the last steps on central differences when the optimizer's are
    # one-sided: a CONVERGED fit is then an optimum to the test's tolerance on any machine
    check = None
    if problem.jac == "2-point":
        check = problem.residual_function(noise, typical=eps0, accurate=True)
    maxiter = 2000 if s.maxiter is None else s.maxiter
    try:
        if lm:
            # one-sided differences in this process: MINPACK's own (compiled, steps
            # sqrt(machine eps) |eps_j|) steer; the status test has the central ones
            own = problem.jac == "2-point" and problem.executor is None
            out = least_squares_lm(raw, eps0, s.tol, maxiter, options, check=check,
                                   differences=own)  # fmt: skip
            if _stalled(out) and s.method != "lm":
                # LM stopped short of an optimum on its own (e.g. NIST BoxBOD from start 1
                # with differences: its first steps send the rate off to infinity): the
                # trust region from eps0, the same status test; the better of the two
                trf = least_squares_scaled(residual, eps0, None, s.tol, maxiter, options,
                                           check=check)  # fmt: skip
                trf.nfev += out.nfev
                if holds(trf.opt, trf.final_error) or trf.loss < out.loss:
                    trf.message = (f"Levenberg-Marquardt stalled ({out.message}); "
                                   f"trust-region reflective from eps0: {trf.message}")  # fmt: skip
                    out = trf
        else:
            out = least_squares_scaled(residual, eps0, bounds, s.tol, maxiter, options,
                                       check=check)  # fmt: skip
    except ConvergenceError as e:
        raise ConvergenceError(f"fit: {e}") from e
    likelihood = gaussian_likelihood(
        residual, n, p, noise, "least squares of a model function",
        residual_columns=lambda e, cols: noise.whiten(problem.jacobian(e, columns=cols,
                                                                       typical=eps0)),
    )  # fmt: skip
    if out.payload is None or out.jacobian is None:
        return dict(
            eps=out.x, loss=np.inf, opt=out.opt, exhausted=out.exhausted,
            failure=out.final_error, label="standard", method="least-squares",
            message=out.message, nit=out.nit, nfev=out.nfev,
            eps_history=out.eps_history, loss_history=out.loss_history,
            verdict=model_verdict(None, None, noise, p, bounds, out.x, failed=out.message),
            likelihood=likelihood, names=problem.names, extra=ModelDetails(),
        )  # fmt: skip
    # the residual and Jacobian the status test judged (no second Jacobian)
    r, J, y = out.residual, np.asarray(out.jacobian, dtype=float), out.payload
    unc = None
    if s.uncertainty:
        if noise.known:
            s2, how, dof = 1.0, "known", None
        else:
            s2, how, dof = float(r @ r) / (n - p) if n > p else np.nan, "estimated", n - p
        if noise.known or n > p:
            try:
                D = least_squares_jacobian(J, problem.names)
            except ValueError as e:
                unc = Uncertainty.failed(f"uncertainty not computed: {e}")
            else:
                # d eps/d(W v) as d eps/dv and the noise as given (the whitened fit saw
                # sigma = 1); the estimate and its names told at once
                unc = estimate_uncertainty(
                    None, out.x, r, s2, how, dof=dof, deps_dv=D,
                    names=None if problem.names is None else list(problem.names),
                    data_noise=noise if noise.known else None,
                )  # fmt: skip
        else:
            unc = Uncertainty.failed("uncertainty not computed: as many parameters as data "
                                     "leave no residual to estimate sigma; pass `sigma`")  # fmt: skip
    if unc is None:
        unc = Uncertainty.failed("not computed (uncertainty=False)")
    verdict = model_verdict(r, noise.whiten(problem.v), noise, p, bounds, out.x)
    message = out.message
    if not holds(out.opt, out.final_error) and callable(problem.jac):
        message += (
            " (a user-supplied `jac` that disagrees with `model` stalls a fit: check it with "
            "problem.check_derivatives(eps))"
        )
    return dict(
        eps=out.x, loss=out.loss, opt=out.opt, exhausted=out.exhausted,
        failure=out.final_error, label="standard", method="least-squares",
        message=message, nit=out.nit, nfev=out.nfev, njev=out.nit,
        eps_history=out.eps_history, loss_history=out.loss_history,
        extra=ModelDetails(prediction=y.reshape(problem.shape)), uncertainty=unc, verdict=verdict,
        likelihood=likelihood, names=problem.names, problem=problem,
    )  # fmt: skip
