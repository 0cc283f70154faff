"""A user's ODE and its readings: :class:`OdeProblem`, its forward sensitivities and its
least-squares fit.

The model is :math:`\\dot y = g(t, y; \\epsilon)`, :math:`y(t_0) = y_0(\\epsilon)`, read at the
data times through an observation operator :math:`H` (every state, some components or a
matrix). The fit integrates with :func:`scipy.integrate.solve_ivp` (``"DOP853"`` by
default, any of its methods for stiff models) together with the forward sensitivities
:math:`S = \\partial y/\\partial\\epsilon`,

.. math::

    \\dot S = J_y S + J_\\epsilon,\\qquad S(t_0) = \\partial y_0/\\partial\\epsilon,

so one solve gives the readings and their Jacobian, to the solver's tolerance. :math:`J_y
S` and :math:`J_\\epsilon` come from the user's ``jac = (jac_y, jac_eps)`` (matrix
products, no loop over parameters) or, without it, from complex steps of ``rhs``
(:math:`\\mathrm{Im}\\,g(t, y + ihS, \\epsilon + ihT_\\epsilon)/h`: its directional
derivatives to machine precision, one call with a column per parameter when ``rhs`` takes
columns) when ``rhs`` is complex-analytic, else one-sided directional differences
(``sensitivities`` of :class:`OdeProblem`; the choice is measured in docs/ode.md).

The standard formulation is a :class:`~ecfm_uq.inverse.problems.model.ModelProblem`
whose model is the solve and whose Jacobian the sensitivities, on the readings present
(a NaN datum is skipped, counted, and reported in the summary): the least-squares driver,
the status from the measured optimality, Gauss-Newton uncertainty, the verdict and the
profile likelihood are that fit's. The exact-match ECFM, forces piecewise constant between
data times, is :mod:`ecfm_uq.inverse.formulations.ode_forces`.
"""

from __future__ import annotations

import copy
import numbers
import warnings

import numpy as np
import scipy.linalg
from scipy.integrate import solve_ivp

from ..._validation import as_finite_array
from ...errors import ConvergenceError
from ..core.details import OdeDetails
from ..core.fitter import Fitter, Outcome
from ..core.series import OdeTrajectory
from ..statistics.loglik import no_likelihood
from .interface import InverseProblem
from .model import ModelProblem, model_fit_fields
from .noise_model import noise_model

__all__ = ["OdeProblem", "OdeStandardFitter", "solve_with_sensitivities"]

_METHODS = ("RK45", "RK23", "DOP853", "Radau", "BDF", "LSODA")
_SQRT_EPS = np.sqrt(np.finfo(float).eps)
#: complex step of the sensitivities: Im g(y + ih S) / h is g's directional derivative
#: to machine precision for any h with h |S| far below the round-off of y and above
#: underflow (no subtraction: nothing cancels); 1e-30 serves directions |S| from 1e-270
#: to about 1e22 times the state's size
_CS_STEP = 1e-30


def solve_with_sensitivities(problem, eps, t_span, y_start, S0, T_eps, G=None, force=None,
                             t_eval=None, dense=False):  # fmt: skip
    """Integrate :math:`\\dot y = g(t, y;\\epsilon) + \\phi` with the sensitivities
    :math:`S` (n, q) along ``q`` directions.

    Column ``j`` of :math:`S` is the derivative of :math:`y` along a direction that moves
    the start state by ``S0[:, j]``, the parameters by ``T_eps[:, j]`` and the constant
    added term :math:`\\phi` by ``G[:, j]``: :math:`\\dot S = J_y S + J_\\epsilon T_\\epsilon
    + G`.

    Parameters
    ----------
    problem : OdeProblem
    eps : (p,) ndarray
    t_span : (2,) floats
    y_start : (n,) ndarray
    S0 : (n, q) ndarray
    T_eps : (p, q) ndarray
    G : (n, q) ndarray, optional
    force : (n,) ndarray, optional
        :math:`\\phi`, added to the right-hand side.
    t_eval : array_like, optional
    dense : bool
        Keep the dense output (``sol.sol``).

    Returns
    -------
    sol : OdeResult
        ``solve_ivp``'s result.
    Y : (n_eval, n) ndarray
    S : (n_eval, n, q) ndarray

    Raises
    ------
    ConvergenceError
        When the integrator fails (a trial point the optimizer backs off from).
    """
    n, q = S0.shape
    rhs, jac = problem.rhs, problem.jac
    phi = np.zeros(n) if force is None else force
    Gc = np.zeros((n, q)) if G is None else G
    moves = np.any(S0 != 0, axis=0) | np.any(T_eps != 0, axis=0)

    if jac is not None:
        jac_y, jac_eps = jac

        def aug(t, z):
            y = z[:n]
            S = z[n:].reshape(n, q)
            dy = np.asarray(rhs(t, y, eps), dtype=float) + phi
            dS = np.asarray(jac_y(t, y, eps)) @ S + np.asarray(jac_eps(t, y, eps)) @ T_eps + Gc
            return np.concatenate((dy, dS.ravel()))

    elif problem.sensitivity_method == "complex-step":
        # Im g(y + ih S_j, eps + ih T_j) / h = J_y S_j + J_eps T_j to machine precision for
        # any h small enough (nothing cancels): one fixed step, far below round-off and far
        # above underflow, for every direction
        hi = _CS_STEP * 1j
        E = eps[:, None] + T_eps * hi  # the parameters' directions: fixed for the solve
        extra = None if G is None else Gc

        def aug(t, z):
            y = z[:n]
            S = z[n:].reshape(n, q)
            f0 = np.asarray(rhs(t, y, eps), dtype=float)
            if problem.vectorized:
                dS = np.asarray(rhs(t, y[:, None] + S * hi, E)).imag / _CS_STEP
            else:
                dS = np.empty((n, q))
                for j in range(q):
                    dS[:, j] = np.asarray(rhs(t, y + S[:, j] * hi, E[:, j])).imag / _CS_STEP
            if extra is not None:
                dS = dS + extra
            return np.concatenate((f0 + phi, dS.ravel()))

    else:
        # constants of the directions' steps, once per solve
        eps_max = float(np.max(np.abs(eps), initial=0.0))
        t_size = np.max(np.abs(T_eps), axis=0, initial=0.0)
        if problem.vectorized:

            def aug(t, z):
                y = z[:n]
                S = z[n:].reshape(n, q)
                f0 = np.asarray(rhs(t, y, eps), dtype=float)
                scale = _SQRT_EPS * max(1.0, float(np.abs(y).max()), eps_max)
                size = np.maximum(np.abs(S).max(axis=0), t_size)
                h = scale / np.where(size > 0, size, 1.0)
                F1 = np.asarray(rhs(t, y[:, None] + h * S, eps[:, None] + h * T_eps), dtype=float)
                dS = (F1 - f0[:, None]) / h + Gc
                return np.concatenate((f0 + phi, dS.ravel()))

        else:

            def aug(t, z):
                y = z[:n]
                S = z[n:].reshape(n, q)
                f0 = np.asarray(rhs(t, y, eps), dtype=float)
                dS = Gc.copy()
                scale = _SQRT_EPS * max(1.0, float(np.abs(y).max()), eps_max)
                for j in np.flatnonzero(moves | np.any(S != 0, axis=0)):
                    size = max(float(np.abs(S[:, j]).max()), float(t_size[j]))
                    if size == 0:
                        continue
                    h = scale / size
                    f1 = np.asarray(rhs(t, y + h * S[:, j], eps + h * T_eps[:, j]), dtype=float)
                    dS[:, j] += (f1 - f0) / h
                return np.concatenate((f0 + phi, dS.ravel()))

    z0 = np.concatenate((y_start, S0.ravel()))
    atol = np.broadcast_to(np.asarray(problem.atol, dtype=float), (n,))
    # the sensitivities out of the error test (CVODES' default, errconS false): the steps
    # the state needs carry them; an error test on them adds steps, not accuracy in y
    s_atol = np.inf if not problem.sensitivity_error_control else np.min(atol)
    atol = np.concatenate((atol, np.full(n * q, s_atol)))
    try:
        sol = solve_ivp(aug, t_span, z0, method=problem.method, t_eval=t_eval,
                        rtol=problem.rtol, atol=atol, dense_output=dense)  # fmt: skip
    except (ValueError, ArithmeticError, np.linalg.LinAlgError) as e:
        raise ConvergenceError(f"solve_ivp at eps={eps.tolist()} raised: {e}") from e
    if sol.status != 0 or not np.all(np.isfinite(sol.y)):
        raise ConvergenceError(
            f"solve_ivp ({problem.method}) failed at eps={eps.tolist()} on "
            f"[{t_span[0]:g}, {t_span[1]:g}]: {sol.message}"
        )
    Z = sol.y.T
    return sol, Z[:, :n], Z[:, n:].reshape(Z.shape[0], n, q)


class OdeProblem(InverseProblem):
    """An ODE :math:`\\dot y = g(t, y;\\epsilon)` and readings of its state at given times.

    Parameters
    ----------
    rhs : callable
        ``rhs(t, y, eps) -> dy/dt`` (as :func:`scipy.integrate.solve_ivp` takes it, with the
        parameters as third argument), shape ``(n_state,)``.
    y0 : (n_state,) array_like or callable
        The initial state at ``t0``, or ``y0(eps) -> (n_state,)`` (initial state from the
        parameters; its derivative is differenced).
    t : (n_t,) array_like
        The data times, strictly increasing, any spacing.
    data : (n_t, n_obs) array_like
        The readings; NaN for a missing one (skipped and counted).
    t0 : float
        The start time, at or before ``t[0]``.
    observe : None, sequence of int or (n_obs, n_state) array_like
        What is read: every state (``None``), these state components, or ``H y``.
    rtol, atol : float
        The integrator's tolerances (``atol`` defaults to ``1e-3 * rtol``, absolute).
    method : str
        A :func:`~scipy.integrate.solve_ivp` method: ``"DOP853"`` (default), ``"RK45"``,
        or ``"LSODA"``/``"BDF"``/``"Radau"`` for stiff models.
    jac : (callable, callable), optional
        ``(jac_y, jac_eps)``: ``jac_y(t, y, eps) -> (n_state, n_state)`` and
        ``jac_eps(t, y, eps) -> (n_state, n_eps)``; else differenced.
    forced : sequence of int, optional
        For ``formulation="ecfm"``: the state component each observed column's force
        drives (one per column of ``data``); default the observed components (required
        with ``observe`` as a matrix).
    vectorized : bool or None
        Without ``jac``: whether ``rhs`` also takes ``y`` of shape ``(n_state, k)`` with
        ``eps`` of shape ``(n_eps, k)`` and returns ``(n_state, k)`` (one column per
        evaluation, as ``solve_ivp(vectorized=True)``), so the sensitivities'
        differences are one call per step stage, not one per parameter. ``None``
        (default) detects it at the fit's start (:meth:`check`: the columns of one call
        equal single calls), else one call per parameter; ``True`` refuses an ``rhs``
        that does not; ``False`` never tries.
    sensitivities : {None, "complex-step", "differences"}
        Without ``jac``, how the sensitivity equations get :math:`J_y S + J_\\epsilon`:
        ``"complex-step"``, :math:`\\mathrm{Im}\\,g(t, y + ihS_j, \\epsilon + ihT_j)/h` with
        ``h`` far below round-off (the directional derivative of ``rhs`` to machine
        precision, so the sensitivities are those of the computed solution; ``rhs`` must
        be complex-analytic: no ``abs``, comparisons, ``float()`` or ``dtype=float``);
        ``"differences"``, one-sided directional differences (error about
        :math:`\\sqrt{\\varepsilon}` relative: the fit then takes about twice the
        evaluations to reach the status test's optimum); ``None`` (default): complex steps
        when :meth:`check` finds ``rhs`` analytic at the fit's start (complex steps agree
        with central differences), else differences. The choice is recorded in
        ``sensitivity_method`` (``"jac"`` with ``jac``). Measured (lynx-hare, rtol 1e-10):
        docs/ode.md.
    sensitivity_error_control : bool
        Whether the integrator's error test includes the sensitivities (default
        ``False``, as CVODES: the steps the state needs carry them, and differenced
        sensitivities would otherwise force tiny steps); ``True`` holds them to ``rtol``
        and the smallest ``atol`` too.
    names : sequence of str, optional
        Parameter names.
    state_names : sequence of str, optional
        State component names (default ``y0``, ``y1``, ...).

    Raises
    ------
    TypeError, ValueError
        Before any integration: unsorted or repeated times, ``t0`` after the first datum,
        ``observe`` that does not fit the data, a malformed argument. ``rhs`` and ``y0(eps)``
        are checked at the fit's ``eps0`` (:meth:`check`).
    """

    formulations = ("standard", "ecfm", "ecfm-random")

    def __init__(self, rhs, y0, t, data, *, t0, observe=None, rtol=1e-8, atol=None,
                 method="DOP853", jac=None, vectorized=None, forced=None,
                 sensitivity_error_control=False, names=None, state_names=None,
                 sensitivities=None):  # fmt: skip
        if not callable(rhs):
            raise TypeError(f"`rhs` must be a callable rhs(t, y, eps) -> dy/dt, got {rhs!r}")
        self.rhs = rhs
        if callable(y0):
            self.y0, self.n_state = y0, None
        else:
            self.y0 = as_finite_array("y0", y0, ndim=1)
            self.n_state = self.y0.size
        self.t = as_finite_array("t", t, ndim=1)
        if self.t.size == 0:
            raise ValueError("`t` must hold at least one data time")
        if np.any(np.diff(self.t) <= 0):
            k = int(np.flatnonzero(np.diff(self.t) <= 0)[0])
            raise ValueError(
                f"`t` must be strictly increasing: t[{k}]={self.t[k]:g} is followed by "
                f"t[{k + 1}]={self.t[k + 1]:g}; sort the data by time and merge repeated times"
            )
        if not isinstance(t0, numbers.Real) or not np.isfinite(t0):
            raise TypeError(f"`t0` must be a finite number (the start time), got {t0!r}")
        self.t0 = float(t0)
        if self.t0 > self.t[0]:
            raise ValueError(
                f"`t0`={self.t0:g} is after the first datum t[0]={self.t[0]:g}: start the "
                "integration at or before the first reading"
            )
        data = np.asarray(data, dtype=float)
        if data.ndim == 1:
            data = data[:, None]
        if data.ndim != 2 or data.shape[0] != self.t.size:
            raise ValueError(
                f"`data` must have shape (len(t), n_obs) = ({self.t.size}, n_obs), got "
                f"{np.shape(data)}"
            )
        if np.any(np.isinf(data)):
            raise ValueError("`data` must be finite or NaN (missing), it holds inf")
        self.v = data
        self._set_observe(observe)
        if not isinstance(method, str) or method not in _METHODS:
            raise ValueError(f"`method` must be one of {_METHODS}, got {method!r}")
        self.method = method
        self.rtol = float(rtol)
        if not self.rtol > 0:
            raise ValueError(f"`rtol` must be positive, got {rtol!r}")
        self.atol = 1e-3 * self.rtol if atol is None else atol
        if np.any(np.asarray(self.atol) <= 0):
            raise ValueError(f"`atol` must be positive, got {atol!r}")
        if jac is not None:
            if not (isinstance(jac, tuple | list) and len(jac) == 2 and all(map(callable, jac))):
                raise TypeError(
                    "`jac` must be a pair (jac_y, jac_eps) of callables (t, y, eps) -> "
                    "(n_state, n_state) and (n_state, n_eps), or None (differenced)"
                )
            jac = tuple(jac)
        self.jac = jac
        if vectorized not in (None, True, False):
            raise TypeError(
                f"`vectorized` must be None (detect), True or False, got {vectorized!r}"
            )
        self._vectorized_asked = vectorized
        self.vectorized = bool(vectorized)
        if sensitivities not in (None, "complex-step", "differences"):
            raise ValueError(
                "`sensitivities` must be None (complex steps when rhs is analytic, else "
                f"differences), 'complex-step' or 'differences', got {sensitivities!r}"
            )
        if jac is not None and sensitivities is not None:
            raise ValueError(
                "`sensitivities` is for an rhs without `jac`: with jac=(jac_y, jac_eps) the "
                "sensitivities use it; pass one or the other"
            )
        self._sensitivities_asked = sensitivities
        #: ``"jac"``, ``"complex-step"`` or ``"differences"`` (decided by :meth:`check`)
        self.sensitivity_method = "jac" if jac is not None else (sensitivities or "differences")
        self.forced = None if forced is None else np.asarray(forced)
        self.sensitivity_error_control = bool(sensitivity_error_control)
        self.names = None if names is None else [str(n) for n in names]
        self._state_names = None if state_names is None else [str(n) for n in state_names]
        self._cache = None

    def _set_observe(self, observe):
        n_obs = self.data.shape[1]
        if observe is None:
            self.observe = None
            if self.n_state is not None and self.n_state != n_obs:
                raise ValueError(
                    f"`data` has {n_obs} columns but the state has {self.n_state} "
                    "components: with observe=None every state is read; pass `observe` "
                    "(the indices read, or an (n_obs, n_state) matrix)"
                )
            return
        obs = np.asarray(observe)
        if obs.ndim == 1 and obs.dtype.kind in "iu":
            if obs.size != n_obs:
                raise ValueError(
                    f"`observe` lists {obs.size} components but `data` has {n_obs} columns"
                )
            if self.n_state is not None and (obs.min() < 0 or obs.max() >= self.n_state):
                raise ValueError(f"`observe` indices must lie in [0, {self.n_state})")
            self.observe = obs.astype(int)
            return
        obs = as_finite_array("observe", observe, ndim=2)
        if obs.shape[0] != n_obs or (self.n_state is not None and obs.shape[1] != self.n_state):
            raise ValueError(
                f"`observe` as a matrix must have shape (n_obs, n_state) = ({n_obs}, "
                f"{self.n_state if self.n_state is not None else 'n_state'}), got {obs.shape}"
            )
        self.observe = obs

    # -- the data ---------------------------------------------------------------------
    @property
    def mask(self):
        """``(n_t, n_obs)`` bool: the readings present (not NaN)."""
        return np.isfinite(self.data)

    @property
    def readings(self):
        """The readings present, time-major (C order), ``(n_data,)``."""
        return self.data[self.mask]

    @property
    def n_data(self):
        """Readings present."""
        return int(self.mask.sum())

    @property
    def n_missing(self):
        """Readings missing (NaN)."""
        return int(self.data.size - self.n_data)

    @property
    def state_names(self):
        """The state components' names."""
        if self._state_names is not None:
            return list(self._state_names)
        return [f"y{i}" for i in range(self.n_state or 0)]

    def H(self):
        """The observation matrix (n_obs, n_state)."""
        n = self.n_state
        if self.observe is None:
            return np.eye(n)
        if self.observe.ndim == 1:
            return np.eye(n)[self.observe]
        return self.observe

    def with_data(self, data):
        """The same problem with other readings of the same shape (NaN where missing)."""
        data = np.asarray(data, dtype=float).reshape(self.data.shape)
        new = copy.copy(self)
        new.v = data
        new.forget_solves()
        return new

    def forget_solves(self):
        self._cache = None

    def log_likelihood(self, formulation, sigma):
        return no_likelihood(formulation)

    # -- checks before any integration ------------------------------------------------
    def initial_state(self, eps):
        """``y0`` or ``y0(eps)``, checked."""
        if not callable(self.y0):
            return self.y0
        y = np.asarray(self.y0(eps), dtype=float)
        if y.ndim != 1 or (self.n_state is not None and y.size != self.n_state):
            raise ValueError(
                f"`y0(eps)` returned shape {y.shape}; it must return the initial state, "
                f"shape ({self.n_state},)"
            )
        return y

    def check(self, eps0):
        """Call ``y0(eps0)`` and ``rhs(t0, y0, eps0)`` once and refuse what does not fit.

        Raises
        ------
        TypeError, ValueError
            Naming the argument and the fix.
        """
        eps0 = as_finite_array("eps0", eps0, ndim=1)
        if callable(self.y0):
            y = np.asarray(self.y0(eps0), dtype=float)
            if y.ndim != 1:
                raise ValueError(f"`y0(eps)` must return a 1-D state, got shape {y.shape}")
            if self.observe is None and y.size != self.v.shape[1]:
                raise ValueError(
                    f"`y0(eps)` returned {y.size} components but `data` has "
                    f"{self.v.shape[1]} columns (observe=None reads every state): return the "
                    "initial state, or pass `observe`"
                )
            if self.n_state is None:
                self.n_state = y.size
                self._set_observe(self.observe)
            elif y.size != self.n_state:
                raise ValueError(f"`y0(eps)` returned {y.size} components, expected {self.n_state}")
        y = self.initial_state(eps0)
        if not np.all(np.isfinite(y)):
            raise ValueError(f"`y0` is not finite at eps0={eps0.tolist()}")
        try:
            dy = np.asarray(self.rhs(self.t0, y, eps0), dtype=float)
        except Exception as e:
            raise type(e)(
                f"`rhs(t0, y0, eps0)` raised {type(e).__name__}: {e}; `rhs` must take (t, y, "
                f"eps) and return dy/dt, shape ({y.size},)"
            ) from e
        if dy.shape != y.shape:
            raise ValueError(
                f"`rhs(t0, y0, eps0)` returned shape {dy.shape}; it must return dy/dt with "
                f"the state's shape ({y.size},)"
            )
        if self._state_names is not None and len(self._state_names) != y.size:
            raise ValueError(f"`state_names` has {len(self._state_names)} entries for {y.size}")
        if self.names is not None and len(self.names) != eps0.size:
            raise ValueError(f"`names` has {len(self.names)} entries for {eps0.size} parameters")
        if self.jac is None and self._vectorized_asked is not False:
            self.vectorized = self._check_vectorized(y, eps0)
        if self.jac is None and self._sensitivities_asked != "differences":
            ok, why = self._check_complex_step(y, eps0)
            if not ok and self._sensitivities_asked == "complex-step":
                raise ValueError(
                    f"sensitivities='complex-step': `rhs` {why} at eps0; it must be "
                    "complex-analytic (no abs, comparisons, float() or dtype=float): write "
                    "it so, or pass sensitivities='differences'"
                )
            self.sensitivity_method = "complex-step" if ok else "differences"
        if self.jac is not None:
            Jy = np.asarray(self.jac[0](self.t0, y, eps0))
            Je = np.asarray(self.jac[1](self.t0, y, eps0))
            if Jy.shape != (y.size, y.size) or Je.shape != (y.size, eps0.size):
                raise ValueError(
                    f"`jac` returned shapes {Jy.shape} and {Je.shape}; expected "
                    f"({y.size}, {y.size}) (d rhs/dy) and ({y.size}, {eps0.size}) (d rhs/deps)"
                )
        return eps0

    def _check_vectorized(self, y, eps0):
        """Whether ``rhs`` evaluates columns: ``rhs(t0, Y, E)`` with ``Y`` (n, k) and ``E``
        (p, k) of distinct columns equals the k single calls. ``vectorized=True`` raises
        when not; ``None`` (auto) falls back to one call per parameter."""
        k = 3
        scale = 1.0 + 1e-3 * np.arange(1, k + 1)
        Yk, Ek = y[:, None] * scale, eps0[:, None] * scale[::-1]
        single = np.column_stack(
            [np.asarray(self.rhs(self.t0, Yk[:, j], Ek[:, j]), dtype=float) for j in range(k)]
        )
        try:
            with np.errstate(all="ignore"):
                F = np.asarray(self.rhs(self.t0, Yk, Ek), dtype=float)
            ok = F.shape == (y.size, k) and np.allclose(F, single, rtol=1e-12, atol=1e-300)
            why = f"returned shape {F.shape}, or columns other than rhs(t0, y_j, eps_j)"
        except Exception as e:  # a user callback that does not take columns
            ok, why = False, f"raised {type(e).__name__}: {e}"
        if not ok and self._vectorized_asked:
            raise ValueError(
                f"vectorized=True: `rhs(t0, Y, E)` with Y ({y.size}, {k}) and E "
                f"({eps0.size}, {k}) {why}; expected ({y.size}, {k}), one column per "
                "evaluation: pass vectorized=False"
            )
        return ok

    def _check_complex_step(self, y, eps0):
        """Whether ``rhs`` is complex-analytic at ``(t0, y, eps0)``: the complex-step
        derivative along a few directions equals central differences (to 1e-6 of the
        derivative's size; they differ by ~1e-10 on an analytic ``rhs``, by O(1) when an
        ``abs``, a comparison or a cast drops the imaginary step), through the call the
        solve will make (columns when ``rhs`` is vectorized). Returns ``(ok, why)``."""
        n, p = y.size, eps0.size
        k = 3  # directions: every state and parameter moved, by distinct amounts
        rng = np.random.default_rng(0)
        dY = (1.0 + np.abs(y))[:, None] * rng.uniform(0.5, 1.5, (n, k))
        dE = (1.0 + np.abs(eps0))[:, None] * rng.uniform(0.5, 1.5, (p, k))
        scale = max(1.0, float(np.abs(y).max()), float(np.abs(eps0).max()))
        with warnings.catch_warnings():
            warnings.simplefilter("error", np.exceptions.ComplexWarning)
            try:
                with np.errstate(all="ignore"):
                    hi = _CS_STEP * 1j  # the solve's step (solve_with_sensitivities)
                    if self.vectorized:
                        F = np.asarray(self.rhs(self.t0, y[:, None] + dY * hi,
                                                eps0[:, None] + dE * hi))  # fmt: skip
                        cs = F.imag / _CS_STEP
                    else:
                        cs = np.empty((n, k))
                        for j in range(k):
                            f = np.asarray(self.rhs(self.t0, y + dY[:, j] * hi,
                                                    eps0 + dE[:, j] * hi))  # fmt: skip
                            cs[:, j] = f.imag / _CS_STEP
            except Exception as e:  # a user callback that does not take complex numbers
                return False, f"raised {type(e).__name__} on complex arguments: {e}"
        if cs.shape != (n, k) or not np.all(np.isfinite(cs)):
            return False, "returned a complex-step derivative of the wrong shape or non-finite"
        cd = np.empty((n, k))
        for j in range(k):
            hj = 1e-5 * scale / max(np.abs(dY[:, j]).max(), np.abs(dE[:, j]).max())
            fp = np.asarray(self.rhs(self.t0, y + hj * dY[:, j], eps0 + hj * dE[:, j]), float)
            fm = np.asarray(self.rhs(self.t0, y - hj * dY[:, j], eps0 - hj * dE[:, j]), float)
            cd[:, j] = (fp - fm) / (2 * hj)
        size = max(float(np.abs(cd).max()), float(np.abs(cs).max()), np.finfo(float).tiny)
        err = float(np.abs(cs - cd).max()) / size
        if err > 1e-6:
            return (
                False,
                f"gives complex-step derivatives {err:.1e} (relative) off central differences",
            )
        return True, ""

    def initial_sensitivity(self, eps):
        """:math:`\\partial y_0/\\partial\\epsilon` (n_state, p): zeros for a fixed ``y0``,
        central differences of ``y0(eps)``."""
        n, p = self.n_state, eps.size
        if not callable(self.y0):
            return np.zeros((n, p))
        D = np.empty((n, p))
        for j in range(p):
            h = 1e-6 * max(1.0, abs(eps[j]))
            e1, e2 = eps.copy(), eps.copy()
            e1[j] += h
            e2[j] -= h
            D[:, j] = (self.initial_state(e1) - self.initial_state(e2)) / (2 * h)
        return D

    # -- the standard model -----------------------------------------------------------
    def solve(self, eps):
        """The state at the data times and its sensitivities to ``eps``:
        ``(Y (n_t, n), S (n_t, n, p))``, cached for the last ``eps``."""
        eps = np.asarray(eps, dtype=float)
        key = eps.tobytes()
        if self._cache is not None and self._cache[0] == key:
            return self._cache[1]
        p = eps.size
        _, Y, S = solve_with_sensitivities(
            self, eps, (self.t0, self.t[-1]), self.initial_state(eps),
            self.initial_sensitivity(eps), np.eye(p), t_eval=self.t,
        )  # fmt: skip
        self._cache = (key, (Y, S))
        return Y, S

    def predict(self, eps):
        """The readings present, predicted at ``eps`` (n_data,)."""
        Y, _ = self.solve(eps)
        return (Y @ self.H().T)[self.mask]

    def predict_jacobian(self, eps):
        """Their derivative in ``eps`` (n_data, p), from the sensitivities."""
        _, S = self.solve(eps)
        return np.einsum("on,tnp->top", self.H(), S)[self.mask]

    def trajectory(self, eps):
        """The solution at ``eps`` with its dense output, from ``t0`` to the last datum."""
        sol = solve_ivp(lambda t, y: self.rhs(t, y, eps), (self.t0, self.t[-1]),
                        self.initial_state(eps), method=self.method, rtol=self.rtol,
                        atol=self.atol, dense_output=True)  # fmt: skip
        return OdeTrajectory(sol.t, sol.y.T, self.state_names, ((self.t0, sol.sol),))

    # -- sigma --------------------------------------------------------------------------
    def noise(self, sigma):
        """``sigma`` as given to :func:`~ecfm_uq.inverse.fit`, for the readings present:
        a number (every reading), ``(n_obs,)`` (per observed component), ``(n_obs, n_obs)``
        (a covariance of the readings at one time, the same at every time), ``(n_t,
        n_obs)`` (per reading, NaN allowed where the datum is missing).

        Returns
        -------
        float or NoiseModel
        """
        if sigma is None:
            return None
        n_t, n_obs = self.data.shape
        s = np.asarray(sigma, dtype=float)
        if s.ndim == 0:
            return noise_model(float(s), self.n_data).scale
        mask = self.mask
        if s.shape == (n_obs, n_obs) and (n_obs > 1 or n_t != 1):
            s = as_finite_array("sigma", s)
            if not np.allclose(s, s.T) or np.any(np.linalg.eigvalsh(s) <= 0):
                raise ValueError(
                    f"`sigma` of shape ({n_obs}, {n_obs}) is the covariance of the readings "
                    "at one time: it must be symmetric positive definite (a sigma per "
                    "reading is given as (len(t), n_obs))"
                )
            blocks = [s[np.ix_(m, m)] for m in mask if m.any()]
            return noise_model(scipy.linalg.block_diag(*blocks), self.n_data)
        if s.shape == (n_obs,):
            s = np.broadcast_to(s, (n_t, n_obs))
        if s.shape != (n_t, n_obs):
            raise ValueError(
                f"`sigma` for an OdeProblem must be a number, ({n_obs},) per observed "
                f"component, ({n_obs}, {n_obs}) a covariance at each time, or ({n_t}, "
                f"{n_obs}) per reading; got shape {s.shape}"
            )
        per = s[mask]
        if not np.all(np.isfinite(per)) or np.any(per <= 0):
            raise ValueError(
                "`sigma` must be positive and finite at every reading present (NaN is "
                "allowed only where the datum is missing)"
            )
        return noise_model(per, self.n_data)

    def readings_model(self):
        """The standard fit's :class:`ModelProblem` on the readings present."""
        return ModelProblem(self.predict, self.readings, jac=self.predict_jacobian,
                            names=self.names)  # fmt: skip


class OdeStandardFitter(Fitter):
    """``OdeProblem``, ``"standard"``: least squares of the readings present
    (:func:`fit_ode_standard`)."""

    kind, formulation, default_method = "ode", "standard", "least-squares"

    def run(self, problem, eps0, settings):
        return fit_ode_standard(problem, eps0, settings)


def fit_ode_standard(problem, eps0, s):
    """:func:`~ecfm_uq.inverse.fit` of an :class:`OdeProblem`, ``formulation="standard"``:
    least squares of the readings present, through
    :func:`~ecfm_uq.inverse.problems.model.model_fit_fields`; an
    :class:`~ecfm_uq.inverse.core.fitter.Outcome` (``fit`` decides the status)."""
    eps0 = problem.check(eps0)
    problem.forget_solves()
    fields = model_fit_fields(problem.readings_model(), eps0, s)
    pred = np.full(problem.data.shape, np.nan)
    try:
        Y, _ = problem.solve(fields["eps"])
        pred = Y @ problem.H().T
        state = problem.trajectory(fields["eps"])
    except ConvergenceError:
        state = None
    extra = OdeDetails(prediction=pred, n_missing=problem.n_missing)
    return Outcome(**{**fields, "state": state, "extra": extra})
