"""Standard and ECFM inverse problems for time-dependent systems (paper Section 3.1).

For any :class:`~ecfm_uq.system.GalerkinSystem` with a mass matrix, marched by
backward Euler (Eq. backward_euler) over :math:`\\mathcal P` steps of size
:math:`\\Delta t`, with data :math:`v_i` measured at every step:

* standard (Eq. inv_obj), the state a function of :math:`\\epsilon`:

  .. math::

      z^{INV}(\\epsilon) = \\frac{\\Delta t}{2}\\sum_{i=1}^{\\mathcal P}
          \\|\\mathcal M\\theta_i - v_i\\|^2,\\qquad
      \\nabla z^{INV} = \\Delta t\\sum_{i=1}^{\\mathcal P}(\\mathcal M\\theta_i - v_i)\\cdot
          \\mathcal M\\frac{\\partial\\theta_i}{\\partial\\epsilon}

  (Eq. grad), with :math:`\\partial\\theta_i/\\partial\\epsilon` from the discrete
  sensitivity equations (Eq. discrete_sens);
* ECFM (Eq. ecfm_obj), the state and the constraint forces functions of :math:`\\epsilon`
  through the augmented Newton system of every step (Eq. ecfm_solve):

  .. math::

      z^{ECFM}(\\epsilon) = \\frac{\\Delta t}{2}\\sum_{i=1}^{\\mathcal P}\\|\\lambda_i\\|^2,
      \\qquad
      \\nabla z^{ECFM} = \\Delta t\\sum_{i=1}^{\\mathcal P}\\lambda_i\\cdot
          \\frac{\\partial\\lambda_i}{\\partial\\epsilon}

  (Eq. ecfm_grad), with :math:`\\partial\\lambda_i/\\partial\\epsilon` from the augmented
  sensitivity system (Eq. discrete_sens_ecfm).

The sensitivities are integrated by :func:`ecfm_uq.system.march` with the factorized
step Jacobian, so a gradient costs little more than a forward solve. For a stochastic
system (``P > 1``) :math:`\\theta_i` is read as the mean :math:`\\Theta_i\\mathbb E[\\Psi]`,
which is also what the ECFM data constraint acts on.

With data at some steps only (``t``, the data times), the standard objective sums over
the data times and the ECFM holds one force over each data interval, matched at the data
times: :mod:`~ecfm_uq.inverse.problems.dynamic_sparse`.
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses

import numpy as np

from ..._validation import as_dense_rows, as_finite_array, check_choice, check_int, check_positive
from ...errors import ConvergenceError, NonIdentifiableError
from ...system import march
from ...system.schemes import SCHEMES
from ...system.step_control import check_steps, check_tolerances, choose_steps
from ..core.gradients import choose_gradient
from ..core.result import Uncertainty
from ..statistics.loglik import least_squares_likelihood, no_likelihood
from ..statistics.uncertainty import estimate_uncertainty, least_squares_jacobian, residual_variance
from .dynamic_sparse import check_data_times, data_derivatives, data_steps, interval_forces
from .force_bases import check_force_basis
from .interface import InverseProblem
from .whitening import dynamic_noise_model, jacobian_in_data_units, whitened_problem

FORMULATIONS = ("standard", "ecfm")
#: the time schemes of a dynamic problem: the fixed-step ones and the frozen adaptive grid
DYNAMIC_SCHEMES = (*SCHEMES, "adaptive")


class DynamicInverseProblem(InverseProblem):
    """A time-dependent model, its initial state, time grid and sensor data.

    Parameters
    ----------
    system : GalerkinSystem
        With a mass matrix ``M``; with constraint forces ``Gamma`` ``(N, C)`` for the ECFM
        formulation.
    Theta0 : (N,) or (N, P) array_like
        Initial state, independent of :math:`\\epsilon`.
    dt : float
        Time step :math:`\\Delta t`.
    n_steps : int
        Number of steps :math:`\\mathcal P`.
    M_obs : (C, N) array_like
        Measurement operator :math:`\\mathcal M`.
    V : (n_steps + 1, C) or (len(t), C) array_like
        Data; row ``i`` is :math:`v_i` at time ``t0 + i * dt`` (row 0, the initial time,
        is not used by either objective); with ``t``, row ``i`` is the reading at
        ``t[i]``. Their noise is ``fit``'s ``sigma``, readings at
        different times independent: one number, one standard deviation per sensor
        ``(C,)`` or a covariance over the sensors ``(C, C)``, the same at every time; or
        one standard deviation per reading ``(n_readings, C)``, the shape of ``V[1:]``
        (:mod:`~ecfm_uq.inverse.problems.whitening`, which says which shape is which).
    t0 : float
        Initial time.
    t : (n_t,) array_like, optional
        The data times, when the data are not at every step: strictly increasing times
        on the step grid ``t0 + k * dt`` within the march (``dt`` dividing the data's
        spacing; the integrator takes ``dt``'s steps between them; with
        ``scheme="adaptive"`` any times in the march, the chosen grid holding them). The standard fit fits
        these readings only; the ECFM holds one force vector over each data interval
        :math:`(t_{j-1}, t_j]` and matches the data at the data times, its objective the
        force function's :math:`L^2`, :math:`\\tfrac12\\sum_j\\Delta t_j|\\lambda_j|^2`
        (:mod:`~ecfm_uq.inverse.problems.dynamic_sparse`). A reading at ``t0`` is not
        fitted (as row 0 without ``t``); without one, ``V`` is stored with the initial
        state's reading as its row 0, so ``problem.V`` has ``len(t) + 1`` rows. ``None``
        (the default), or every step: data at every step, the paper's problem.
    solve_tol : float
        Newton tolerance per step on :math:`\\|R\\|_2`.
    solve_maxiter : int
        Newton iterations per step.
    gradient : {"auto", "forward", "adjoint"}
        Gradients by forward sensitivities (Eqs. discrete_sens, discrete_sens_ecfm) or by
        the discrete adjoint of the march (one backward pass of transposed solves with
        the forward factors, whatever ``n_eps``); ``"auto"`` takes the adjoint when
        ``n_eps > 1``.
    solver : str, SolverOptions or dict
        Linear solver of every step (see :func:`ecfm_uq.system.march`).
    warm_start : bool
        Start each step's Newton iteration from the last trajectory of the same
        formulation (the previous optimizer iterate's) instead of the previous step: fewer
        Newton iterations, the same solution to ``solve_tol``.
    scheme : {"euler", "bdf2", "adaptive"}
        Time scheme of the march (:mod:`ecfm_uq.system.schemes`): backward Euler (the
        paper's, the default) or the second-order BDF2 with the step ``dt``; or
        ``"adaptive"``: the variable-step BDF2 on a grid through the data times chosen
        to meet ``rtol``/``atol`` (:func:`ecfm_uq.system.step_control.choose_steps`) at
        the first parameters marched (a fit: ``eps0``) and then *frozen*, so that every
        gradient is the exact derivative of the discrete objective being minimized
        (:meth:`freeze_steps`, :attr:`steps`; a fit re-checks the grid at its estimate).
        Sensitivities and adjoint gradients are exact for the scheme that runs.
    rtol, atol : float, optional
        ``scheme="adaptive"`` only: the local error tolerances of every step (default
        ``rtol=1e-6``; ``atol`` ``rtol * max|Theta0|``, ``rtol`` when ``Theta0 = 0``).
        With ``"adaptive"`` the data times ``t`` need not be on the ``dt`` grid (the
        chosen grid holds them); the ECFM then holds its forces in the basis
        ``force_basis`` between the data times, matched at them, on the frozen grid.
    force_basis : {"constant", "linear"} or {"rbf": width}
        The ECFM force in time with data times ``t`` or ``scheme="adaptive"``
        (:mod:`~ecfm_uq.inverse.problems.force_bases`): one force per data interval
        (the default), continuous piecewise linear (hat functions at the data times), or
        Gaussians centred at the data times of the given width (time units); the
        objective the force function's :math:`L^2`. With data at every step of a fixed
        scheme and ``"constant"``: the paper's per-step forces.

    Raises
    ------
    ValueError
        On misshaped or non-finite data, a system without mass matrix, a
        non-positive ``dt``/``solve_tol``/``rtol``, an unknown ``scheme``, ``rtol``/``atol``
        with a fixed-step scheme, or data times ``t`` off the step grid, unsorted,
        repeated or outside the march.
    """

    def __init__(
        self,
        system,
        Theta0,
        dt,
        n_steps,
        M_obs,
        V,
        *,
        t0=0.0,
        t=None,
        solve_tol=1e-10,
        solve_maxiter=30,
        gradient="auto",
        solver="auto",
        warm_start=True,
        scheme="euler",
        rtol=None,
        atol=None,
        force_basis="constant",
    ):
        if getattr(system, "M", None) is None:
            raise ValueError("`system` needs a mass matrix M for time stepping (build it with M=)")
        self.system = system
        self.dt = check_positive("dt", dt)
        self.n_steps = check_int("n_steps", n_steps, minimum=1)
        self.t0 = float(as_finite_array("t0", t0, ndim=0))
        self.solve_tol = check_positive("solve_tol", solve_tol)
        self.solve_maxiter = check_int("solve_maxiter", solve_maxiter, minimum=1)
        self.gradient = choose_gradient(gradient, system.n_eps)
        self.solver = solver
        self.warm_start = bool(warm_start)
        if not isinstance(scheme, str) or scheme not in DYNAMIC_SCHEMES:
            raise ValueError(
                f"`scheme` must be one of {DYNAMIC_SCHEMES}, got {scheme!r} ('adaptive': "
                "steps chosen to meet rtol/atol, then frozen)"
            )
        self.scheme = scheme
        if scheme != "adaptive" and (rtol is not None or atol is not None):
            raise ValueError(
                f"`rtol`/`atol` set the steps of scheme='adaptive'; scheme={scheme!r} marches "
                "the fixed step `dt` (pass scheme='adaptive', or drop rtol/atol)"
            )
        self.rtol, self.atol = check_tolerances(1e-6 if rtol is None else rtol, atol)
        check_force_basis(force_basis)
        self.force_basis = force_basis
        self.steps = None  # the frozen StepSequence of scheme="adaptive"
        self._last = {}  # formulation -> last trajectory (the warm start)
        N, P = system.shape
        self.Theta0 = system.check_initial_state(Theta0)
        self.M_obs = as_dense_rows("M_obs", M_obs)
        if self.M_obs.shape[1] != N:
            raise ValueError(f"`M_obs` must have N = {N} columns, got shape {self.M_obs.shape}")
        C = self.M_obs.shape[0]
        self._forces = None  # the IntervalForces of data at some steps (built when needed)
        self._weight = self.dt  # z = weight/2 * sum of squared residuals (standard)
        if t is not None and self.adaptive:  # any times: the chosen grid will hold them
            return self._set_data_times(t, V, C)
        steps = None if t is None else data_steps(t, self.t0, self.dt, self.n_steps)
        if steps is not None and np.array_equal(steps, np.arange(self.n_steps + 1)):
            steps = None  # data at every step: the paper's problem
        if steps is None:
            self.V = as_finite_array("V", V, shape=(self.n_steps + 1, C))
            self._rows = np.arange(self.n_steps + 1)  # the data times' rows of a trajectory
        else:
            V = as_finite_array("V", V, shape=(steps.size, C))
            if steps[0] != 0:  # row 0 is the initial time's (not fitted): its reading
                V = np.vstack([self.Theta0 @ system.E1 @ self.M_obs.T, V])
                steps = np.r_[0, steps]
            if steps.size < 2:
                raise ValueError("`t` has no data time after t0: nothing to fit")
            self.V = V
            self._rows = steps
            self._weight = self.dt * steps[-1] / (steps.size - 1)  # the mean data spacing
        self.sparse = steps is not None
        #: the data times, the rows of V
        self.t = self.t0 + self.dt * self._rows

    def _set_data_times(self, t, V, C):
        """Data times off any ``dt`` grid (``scheme="adaptive"``): ``t`` and ``V`` stored
        with the initial time as row 0; the rows of a trajectory (``_rows``) are known
        once a grid is frozen (:meth:`freeze_steps`; until then, placeholders)."""
        t = check_data_times(t, self.t0, self.t0 + self.n_steps * self.dt)
        V = as_finite_array("V", V, shape=(t.size, C))
        if t[0] > self.t0 + 1e-12 * (t[-1] - self.t0):
            V = np.vstack([self.Theta0 @ self.system.E1 @ self.M_obs.T, V])
            t = np.r_[self.t0, t]
        else:
            t = np.r_[self.t0, t[1:]]
        if t.size < 2:
            raise ValueError("`t` has no data time after t0: nothing to fit")
        self.V, self.t, self.sparse = V, t, True
        self._rows = np.arange(t.size)
        self._weight = (t[-1] - t[0]) / (t.size - 1)  # the mean data spacing

    @property
    def _by_interval(self):
        """The ECFM forces are functions of time in a basis (data times ``t``, or an
        adaptive grid, or a basis other than ``"constant"``), not the paper's per step."""
        return self.sparse or self.adaptive or self.force_basis != "constant"

    @property
    def adaptive(self):
        """True for ``scheme="adaptive"`` (a frozen error-controlled grid)."""
        return self.scheme == "adaptive"

    def freeze_steps(self, eps, refine=False):
        """Choose the step sequence at ``eps`` to meet ``rtol``/``atol`` and freeze it
        (``scheme="adaptive"``): every later march, gradient and fit uses this grid until
        the next call (``refine=True``: by splitting the frozen grid's steps instead of
        starting from the data times). Returns the
        :class:`~ecfm_uq.system.step_control.StepSequence`.

        Raises
        ------
        ConvergenceError
            The model cannot be marched at ``eps`` (the message names the time reached),
            or no grid within the limits meets the tolerance.
        """
        if not self.adaptive:
            raise ValueError(f"freeze_steps is for scheme='adaptive', not {self.scheme!r}")
        eps = self.system.check_eps(eps)
        at = f"choosing the steps at eps={np.array2string(eps)} failed"
        t_data = self.t  # the data times, the rows of V
        try:
            seq = choose_steps(
                self.system, eps, self.Theta0, t_data, rtol=self.rtol, atol=self.atol,
                tol=self.solve_tol, maxiter=self.solve_maxiter, solver=self.solver,
                start=self.steps.times if refine and self.steps is not None else None,
            )  # fmt: skip
        except ConvergenceError as e:
            raise ConvergenceError(f"{at}: {e}") from e
        if not seq.met:
            raise ConvergenceError(f"{at}: {seq.message}")
        self.steps, self._rows, self._last = seq, seq.data_index, {}
        self._forces = None  # the forces' basis lives on the grid
        return seq

    def check_steps(self, eps):
        """The local errors of the frozen grid marched at ``eps`` against ``rtol``/``atol``
        (a :class:`~ecfm_uq.system.step_control.StepSequence`; ``met`` says whether every
        step meets them)."""
        if self.steps is None:
            raise ValueError("no frozen steps: scheme='adaptive' and freeze_steps(eps) first")
        saved = dict(self._last)  # a check must not move the optimizer's warm starts
        try:
            traj = self.solve(eps, "standard")
        finally:
            self._last = saved
        return check_steps(traj, self._rows, self.steps.rtol, self.steps.atol)

    data_attribute = "V"

    #: ``(n_readings + 1, C)``: the standard deviation of every reading (row 0, unused: 1)
    #: in a copy whitened for a sigma per reading
    #: (:func:`~ecfm_uq.inverse.problems.whitening.whitened_problem`, the only place that sets
    #: it): its ``V`` and its predicted readings are then divided by it, and so is every
    #: residual and derivative formed from them. ``None``: the data's units.
    reading_sigma = None

    @property
    def n_sensors(self):
        """Number of sensors C."""
        return self.M_obs.shape[0]

    @property
    def n_data(self):
        """Number of readings fitted, ``n_readings * C`` (``V[0]`` is the initial time)."""
        return int(np.size(self.V[1:]))

    @property
    def data_steps(self):
        """The trajectory row (step index) of every row of ``V``, ``(n_readings + 1,)``:
        ``trajectory.Theta[problem.data_steps]`` are the states at the data times, and for
        the ECFM with data times ``t`` ``forces[problem.data_steps[1:]]`` the force of
        each data interval."""
        return np.array(self._rows)

    @property
    def n_readings(self):
        """Number of data times fitted (``n_steps``, or the data times after ``t0``)."""
        return self.V.shape[0] - 1

    def forget_solves(self):
        """A copy with other data starts cold (no warm start from the old data's fits)."""
        self._last = {}

    @contextlib.contextmanager
    def warm_starts_kept(self):
        """A context in which solves leave the optimizer's warm starts as they were (a
        check at one point, e.g. the status test or the verdict, must not move them)."""
        saved = dict(self._last)
        try:
            yield self
        finally:
            self._last = saved

    def with_force_basis(self, force_basis):
        """This problem with the ECFM forces in ``force_basis``
        (:mod:`~ecfm_uq.inverse.problems.force_bases`): itself when it has that basis, else a
        copy with its own forces and ECFM warm starts (the rest shared)."""
        check_force_basis(force_basis)
        if force_basis == self.force_basis:
            return self
        other = copy.copy(self)
        other.force_basis, other._forces = force_basis, None
        other._last = {k: w for k, w in self._last.items() if not k.startswith("ecfm")}
        return other

    # -- forward solves --------------------------------------------------------------------
    def solve(self, eps, formulation="standard", sensitivities=False, keep_factors=False):
        """March the model at ``eps``; ``"ecfm"`` adds the data constraint at every step.

        Returns
        -------
        Trajectory

        Raises
        ------
        ConvergenceError
            If Newton fails at some step; the message names the step, its time and the
            residual norm.
        """
        formulation = check_choice("formulation", formulation, FORMULATIONS)
        constraint = None
        if formulation == "ecfm":  # M theta_i = v_i: in the data's units (same solutions)
            if self.system.n_forces != self.n_sensors:
                raise ValueError(
                    f"the ECFM formulation needs one constraint force per sensor: the system "
                    f"has {self.system.n_forces} (Gamma), the data {self.n_sensors} sensors"
                )
            constraint = (self.M_obs, self._in_data_units(self.V))
        eps = self.system.check_eps(eps)
        if constraint is not None and self._by_interval:
            return self._interval_forces(eps, sensitivities)[0]
        if self.adaptive and self.steps is None:
            self.freeze_steps(eps)
        grid = dict(dt=self.dt, n_steps=self.n_steps, t0=self.t0)
        if self.adaptive:
            grid = dict(times=self.steps.times)
        try:
            traj = march(
                self.system,
                eps,
                self.Theta0,
                **grid,
                constraint=constraint,
                sensitivities=sensitivities,
                tol=self.solve_tol,
                maxiter=self.solve_maxiter,
                strict=True,
                solver=self.solver,
                keep_factors=keep_factors,
                guess=self._last.get(formulation) if self.warm_start else None,
                scheme="bdf2" if self.adaptive else self.scheme,
            )
        except ConvergenceError as e:
            if self.warm_start and formulation in self._last:
                # a warm start far from this eps can mislead Newton: retry cold
                del self._last[formulation]
                return self.solve(eps, formulation, sensitivities, keep_factors)
            raise ConvergenceError(
                f"{formulation} forward solve at eps={np.array2string(eps)} failed: {e}"
            ) from e
        if self.warm_start:
            self._last[formulation] = traj
        return traj

    def _interval_forces(self, eps, sensitivities=False):
        """The ECFM with data at some steps (:func:`.dynamic_sparse.interval_forces`)."""
        return interval_forces(self, eps, sensitivities)

    def predictions(self, trajectory):
        """Sensor readings of the mean state, :math:`\\mathcal M\\,\\Theta_i\\mathbb E[\\Psi]`,
        at the data times (the rows of ``V``), in the units of ``V`` (divided by
        :attr:`reading_sigma` in a copy whitened per reading).

        Returns
        -------
        (n_readings + 1, C) ndarray
        """
        return self._whiten(trajectory.Theta[self._rows] @ self.system.E1 @ self.M_obs.T)

    # the one place a sigma per reading enters (reading_sigma): readings, their derivatives
    def _whiten(self, readings, rows=slice(None)):
        """Readings ``(n_rows, C, ...)`` of the data rows ``rows`` in the units of ``V``."""
        if self.reading_sigma is None:
            return readings
        s = self.reading_sigma[rows]
        return readings / s.reshape(s.shape + (1,) * (np.ndim(readings) - 2))

    def _in_data_units(self, V):
        return V if self.reading_sigma is None else V * self.reading_sigma

    def _reading_sensitivities(self, traj):
        """:math:`\\partial(\\mathcal M\\theta_i)/\\partial\\epsilon` at the data times
        ``i = 1..n_steps`` in the units of ``V``, ``(n_steps, C, n_eps)``."""
        dmean = np.einsum("tikm,k->tim", traj.dTheta[self._rows[1:]], self.system.E1)
        return self._whiten(np.einsum("cj,tjm->tcm", self.M_obs, dmean), slice(1, None))

    # -- objectives ------------------------------------------------------------------------
    def standard_objective(self, eps, gradient=True):
        """:math:`z^{INV}` (Eq. inv_obj) and its gradient (Eqs. grad, discrete_sens).

        With data times ``t``: the sum over the readings at the data times, weighted by
        the mean data spacing :math:`\\bar w = (t_J - t_0)/J` instead of :math:`\\Delta t`.

        Parameters
        ----------
        eps : (n_eps,) array_like
        gradient : bool
            Integrate the sensitivities and return the gradient (else ``None``).

        Returns
        -------
        z : float
        grad : (n_eps,) ndarray or None
        trajectory : Trajectory
        """
        adjoint = gradient and self.gradient == "adjoint"
        traj = self.solve(
            eps, "standard", sensitivities=gradient and not adjoint, keep_factors=adjoint
        )
        e = self.predictions(traj)[1:] - self.V[1:]  # (P, C), i = 1..P
        z = 0.5 * self._weight * float(np.sum(e * e))
        if not gradient:
            return z, None, traj
        if adjoint:  # dz/dTheta_i = dt (e_i / sigma_i) M E1^T: de_i/d(M theta_i) = 1/sigma_i
            g = np.zeros(traj.Theta.shape)
            e_load = self._whiten(e, slice(1, None))
            g[self._rows[1:]] = self._weight * np.einsum(
                "tc,cj,k->tjk", e_load, self.M_obs, self.system.E1
            )
            return z, traj.adjoint_gradient(g), traj
        de = self._reading_sensitivities(traj)  # (P, C, n_eps)
        return z, self._weight * np.einsum("tc,tcm->m", e, de), traj

    def ecfm_objective(self, eps, gradient=True):
        """:math:`z^{ECFM}` (Eq. ecfm_obj) and its gradient (Eqs. ecfm_grad,
        discrete_sens_ecfm).

        Returns
        -------
        z : float
        grad : (n_eps,) ndarray or None
        trajectory : Trajectory
            ``trajectory.lam`` ``(n_steps + 1, C)`` are the constraint forces (with data
            times ``t``: the force of each data interval, held over its steps;
            :math:`z = \\tfrac12\\sum_j\\Delta t_j|\\lambda_j|^2` over the intervals and its
            gradient by forward sensitivities).
        """
        if self._by_interval:  # z = lam^T W lam / 2, W the basis' Gram matrix (x I_C)
            traj, lam, dlam, _ = self._interval_forces(self.system.check_eps(eps), gradient)
            Wl = self._forces.W @ lam.ravel()
            z = 0.5 * float(lam.ravel() @ Wl)
            if not gradient:
                return z, None, traj
            return z, Wl @ dlam.reshape(lam.size, -1), traj
        adjoint = gradient and self.gradient == "adjoint"
        traj = self.solve(eps, "ecfm", sensitivities=gradient and not adjoint, keep_factors=adjoint)
        lam = traj.lam[1:]
        z = 0.5 * self.dt * float(np.sum(lam * lam))
        if not gradient:
            return z, None, traj
        if adjoint:
            g_lam = np.zeros_like(traj.lam)
            g_lam[1:] = self.dt * lam
            return z, traj.adjoint_gradient(np.zeros(traj.Theta.shape), g_lam), traj
        return z, self.dt * np.einsum("tc,tcm->m", lam, traj.dlam[1:]), traj

    def residual(self, eps, formulation="standard"):
        """The residual vector of the trajectory objective and its sensitivity Jacobian.

        :math:`z = \\tfrac12\\|r\\|^2` with :math:`r = \\sqrt{\\Delta t}\\,
        (\\mathcal M\\theta_i - v_i)_{i=1..\\mathcal P}` (standard) or
        :math:`\\sqrt{\\Delta t}\\,(\\lambda_i)_{i=1..\\mathcal P}` (ECFM), stacked
        (with data times ``t``: :math:`\\sqrt{\\bar w}` and the readings at the data times;
        :math:`\\sqrt{\\Delta t_j}\\lambda_j` over the data intervals);
        :math:`J = \\partial r/\\partial\\epsilon` by forward sensitivities (one extra
        solve per parameter and step with the factored step Jacobian).

        Returns
        -------
        r : (n_steps C,) ndarray
        J : (n_steps C, n_eps) ndarray
        trajectory : Trajectory
        """
        formulation = check_choice("formulation", formulation, FORMULATIONS)
        n_eps = self.system.n_eps
        if formulation == "ecfm" and self._by_interval:  # R lam, R^T R = W (Gram x I_C)
            traj, lam, dlam, _ = self._interval_forces(self.system.check_eps(eps), True)
            R = self._forces.root
            return R @ lam.ravel(), R @ dlam.reshape(lam.size, n_eps), traj
        traj = self.solve(eps, formulation, sensitivities=True)
        h = np.sqrt(self._weight)  # dt with data at every step
        if formulation == "ecfm":
            return h * traj.lam[1:].ravel(), h * traj.dlam[1:].reshape(-1, n_eps), traj
        e = self.predictions(traj)[1:] - self.V[1:]
        de = self._reading_sensitivities(traj)
        return h * e.ravel(), h * de.reshape(-1, n_eps), traj

    def objective(self, formulation):
        """The callable ``eps -> (z, grad)`` of one formulation (for optimizers)."""
        formulation = check_choice("formulation", formulation, FORMULATIONS)
        method = self.standard_objective if formulation == "standard" else self.ecfm_objective

        def fun_and_grad(eps):
            z, g, _ = method(eps, gradient=True)
            return z, g

        return fun_and_grad

    def loss(self, eps, formulation):
        """Objective value only (one forward solve, no sensitivities)."""
        formulation = check_choice("formulation", formulation, FORMULATIONS)
        method = self.standard_objective if formulation == "standard" else self.ecfm_objective
        return method(eps, gradient=False)[0]

    def log_likelihood(self, formulation, sigma):
        """The :class:`~ecfm_uq.inverse.statistics.loglik.LogLikelihood` of a standard fit: Gaussian least squares
        over the ``n = P C`` readings (sigma known, or profiled out), or why there is none.
        ``sigma`` an array (per sensor, a covariance over the sensors, or per reading;
        :mod:`ecfm_uq.inverse.problems.whitening`): that of the whitened readings."""
        if formulation != "standard":
            return no_likelihood(formulation)
        noise = dynamic_noise_model(sigma, self.n_readings, self.n_sensors)
        if noise.kind in ("diagonal", "covariance"):
            like = whitened_problem(self, noise).log_likelihood(formulation, 1.0)
            what = f"trajectory least squares, Gaussian noise {noise.describe()}"
            return dataclasses.replace(like, description=what)
        sigma = noise.scale
        dt = self._weight

        def rss(eps):  # z = dt/2 * sum of squared residuals over the P readings
            z, g, _ = self.standard_objective(eps, gradient=True)
            return 2.0 * z / dt, 2.0 * g / dt

        def rss_only(eps):
            return 2.0 * self.loss(eps, "standard") / dt

        return least_squares_likelihood(
            rss, int(np.size(self.V[1:])), self.system.n_eps, sigma,
            "trajectory least squares", rss_only,
        )  # fmt: skip

    # -- optimization ----------------------------------------------------------------------

    def uncertainty(self, eps, formulation="ecfm", sigma=None, covariance="implicit"):
        """Delta-method uncertainty of an estimate of ``eps`` from the data ``V``.

        ``covariance="implicit"`` (this method's default; the full Hessian, the sandwich
        :math:`H^{-1}J^TJH^{-1}s^2` for the standard formulation) or ``"gauss-newton"``
        (the curvature taken as :math:`J^TJ` with :math:`J` the stacked residual's
        Jacobian, :meth:`residual`; :math:`s^2(J^TJ)^{-1}` for the standard formulation,
        the default of :func:`~ecfm_uq.inverse.fit`).

        The estimate is defined by :math:`\\nabla_\\epsilon z(\\epsilon; V) = 0` (Eq.
        grad, or Eq. ecfm_grad); :func:`~ecfm_uq.inverse.statistics.uncertainty.implicit_covariance`
        differentiates that condition in :math:`\\epsilon` and in every datum
        :math:`V_{tc}`, ``t >= 1`` (row 0 is unused by both objectives), with i.i.d.
        noise: :math:`\\sigma^2` given, or :math:`s^2 = \\|r\\|^2/(n_{data} - n_\\epsilon)`
        from the unforced model's residual at ``eps`` (Student-t intervals then). Adam
        stops near, not at, the stationary point; the linearization is taken there.
        ``sigma`` an array (per sensor, a covariance over the sensors, or per reading; the
        shapes of :func:`~ecfm_uq.inverse.fit`): the same computation on the whitened
        problem (:mod:`ecfm_uq.inverse.problems.whitening`), ``jacobian`` in the data's units.
        The ECFM with data times ``t`` and ``"gauss-newton"``: :math:`d\\hat\\epsilon/dv =
        -J^+\\,\\partial r/\\partial v` with the forces' exact derivative in the data,
        :math:`G_\\lambda^{-1}` (:func:`~.dynamic_sparse.data_derivatives`), no differencing.

        Returns
        -------
        Uncertainty
            ``cov``, ``stderr``, ``intervals``, ``noise_model``, ``jacobian`` (n_eps,
            n_steps C), ...; or ``success=False`` and the ``message`` why not.
        """
        formulation = check_choice("formulation", formulation, FORMULATIONS)
        eps = self.system.check_eps(eps)
        if sigma is not None and np.ndim(sigma) > 0:  # whitened once, as fit does
            noise = dynamic_noise_model(sigma, self.n_readings, self.n_sensors)
            if noise.kind != "scalar":
                unc = whitened_problem(self, noise).uncertainty(eps, formulation, 1.0, covariance)
                return dataclasses.replace(
                    unc, jacobian=jacobian_in_data_units(unc.jacobian, noise)
                )
            sigma = noise.scale
        try:
            if sigma is not None:
                s2, model, dof = check_positive("sigma", sigma) ** 2, "known", None
            else:
                r = self.predictions(self.solve(eps, "standard"))[1:] - self.V[1:]
                s2, model, dof = residual_variance(r, eps.size), "estimated", r.size - eps.size
                if s2 <= 0:
                    raise ValueError("the residual is zero (noise-free data): pass `sigma`")
        except (ConvergenceError, ValueError) as e:
            return Uncertainty.failed(f"uncertainty not computed: {e}")
        if covariance not in ("implicit", "gauss-newton"):
            raise ValueError(
                f"`covariance` must be 'implicit' or 'gauss-newton', got {covariance!r}"
            )
        other = copy.copy(self)  # the same problem with perturbed data
        other._last = dict(self._last)

        def grad(e, w):
            other.V = np.vstack([self.V[:1], w.reshape(self.n_readings, -1)])
            return other.objective(formulation)(e)[1]

        data = self.V[1:].ravel()
        if covariance == "implicit":
            return estimate_uncertainty(grad, eps, data, s2, model, dof=dof)

        saved = dict(self._last)
        try:
            if formulation == "ecfm" and self._by_interval:  # the forces' data derivative
                _, J, dr_dv = data_derivatives(self, eps)
            else:
                _, J, _ = self.residual(eps, formulation)
        except ConvergenceError as e:
            return Uncertainty.failed(f"uncertainty not computed: {e}")
        finally:
            self._last = saved
        if formulation == "ecfm" and self._by_interval:
            # r = R lam(eps, V): d eps_hat / dV = -J^+ dr/dV (Gauss-Newton)
            try:
                D = -least_squares_jacobian(J) @ dr_dv
            except NonIdentifiableError as e:
                return Uncertainty.failed(f"uncertainty not computed: {e}")
            return estimate_uncertainty(None, eps, data, s2, model, dof=dof, deps_dv=D)
        if formulation == "standard":
            # r = sqrt(dt) (M theta - V): d eps_hat / dV = sqrt(dt) J^+
            try:
                D = np.sqrt(self._weight) * least_squares_jacobian(J)
            except NonIdentifiableError as e:
                return Uncertainty.failed(f"uncertainty not computed: {e}")
            return estimate_uncertainty(None, eps, data, s2, model, dof=dof, deps_dv=D)
        return estimate_uncertainty(grad, eps, data, s2, model, dof=dof, hessian=J.T @ J)
