"""Burgers' equation with unknown viscosity and source scale (paper Section 3.1).

True system (Eq. burgers) and parameterized model (Eq. burgers_param)

.. math::

    w_t + w\\,w_x = 10^{-\\epsilon_1} w_{xx} + \\epsilon_2\\, s(x, t)
        \\;(+ \\textstyle\\sum_j \\lambda_j(t)\\,\\Gamma(x - x_j)),
    \\qquad w(0, t) = w(1, t) = 0,\\quad w(x, 0) = u_0(x),

on :math:`x \\in [0, 1]`, :math:`t \\in [0, T]`, with :math:`u_0 = \\sin(2\\pi x)` and
:math:`s = \\sin(2\\pi x)\\sin(2\\pi t)`. The Galerkin discretization on the sine basis
:math:`f_i = \\sin(i\\pi x)` gives (paper, the system above Eq. backward_euler, and
Eq. burgers_ecfm with constraint forces)

.. math::

    M_{ij}\\dot\\theta_j + A_{ijk}\\theta_j\\theta_k + 10^{-\\epsilon_1}K_{ij}\\theta_j
        = \\epsilon_2 F_i(t) + \\Gamma_{ij}\\lambda_j,

:math:`M_{ij} = \\int f_i f_j`, :math:`K_{ij} = \\int f_i' f_j'`,
:math:`A_{ijk} = \\int f_i f_j f_k'` (so that :math:`A_{ijk}\\theta_j\\theta_k =
\\int f_i\\,w\\,w_x`), :math:`F_i(t) = \\int s(x, t) f_i`,
:math:`\\Gamma_{ij} = \\int f_i\\,h_j` with hat functions :math:`h_j` centred on the
sensors, and the measurement operator :math:`\\mathcal M_{ij} = f_j(x_i)`.
Time stepping is backward Euler (Eq. backward_euler), done by
:func:`ecfm_uq.system.march`; this module only builds the system.

The same builder gives a random viscosity (a stochastic Galerkin system with
:math:`P > 1`): with ``viscosity_chaos=ChaosBasis(order)`` the log-viscosity is
:math:`\\epsilon_1(\\omega) = \\epsilon_1 + \\delta(\\omega - 1/2)`,
:math:`\\omega \\sim U(0, 1)`, so the diffusion term becomes
:math:`10^{-\\epsilon_1} K\\,\\Theta\\,G` with
:math:`G_{k\\ell} = \\mathbb E[10^{-\\delta(\\omega - 1/2)}\\Psi_k\\Psi_\\ell]`
(paper Eq. pce for a coefficient that is a function of the germ).
"""

from __future__ import annotations

import numpy as np

from .._validation import as_finite_array, check_choice, check_int, check_positive
from ..spectral import SineBasis, hat_forces, load, mass, project, sensor_matrix, stiffness, triple
from ..system import Coefficient, GalerkinSystem, LinearTerm, LoadTerm, QuadraticTerm, march

#: The paper's settings (Section 3.1).
PAPER_TRUE_EPS = (1.75, 1.0)
PAPER_SENSORS = (0.2, 0.4, 0.6, 0.8)
INITIAL_STATES = ("projection", "paper")


def initial_condition(x):
    """:math:`u_0(x) = \\sin(2\\pi x)`."""
    return np.sin(2.0 * np.pi * np.asarray(x, dtype=float))


def source_shape(x):
    """Spatial factor of the source, :math:`\\sin(2\\pi x)`."""
    return np.sin(2.0 * np.pi * np.asarray(x, dtype=float))


def source_time(t):
    """Temporal factor of the source, :math:`\\sin(2\\pi t)`."""
    return np.sin(2.0 * np.pi * t)


def source(x, t):
    """:math:`s(x, t) = \\sin(2\\pi x)\\sin(2\\pi t)`."""
    return source_shape(x) * source_time(t)


def hat(x, center, half_width):
    """Unit-height hat :math:`\\max(0, 1 - |x - x_c|/a)` (the constraint-force shape)."""
    return np.maximum(0.0, 1.0 - np.abs(np.asarray(x, dtype=float) - center) / half_width)


class ConvectionForm:
    """The Burgers convection form :math:`q(x, y)_i = A_{ijk} x_j y_k` on a sine basis.

    :math:`A_{ijk} = \\int_0^1 f_i f_j f_k'` (paper Section 3.1), so
    :math:`q(x, y)_i = \\int_0^1 f_i\\,(\\textstyle\\sum_j x_j f_j)(\\sum_k y_k f_k')`. Instead of
    contracting the dense ``(N, N, N)`` tensor it evaluates the fields at the nodes of the
    ``n``-point midpoint rule and integrates there. The rule is exact: a product
    :math:`\\sin(i\\pi x)\\sin(j\\pi x)\\cos(k\\pi x)` is a sum of :math:`\\cos(m\\pi x)`
    with :math:`0 \\le m \\le 3N`, and the midpoint rule integrates :math:`\\cos(m\\pi x)`
    exactly for every :math:`0 \\le m < 2n`; ``n = 3N // 2 + 1`` suffices (the "3/2 rule"
    of dealiased spectral methods). It satisfies the quadratic-form protocol of
    :class:`ecfm_uq.system.QuadraticTerm` (``size``, ``apply``, ``matrix``) at a cost of
    :math:`O(N n)` per product instead of :math:`O(N^3)`.

    Parameters
    ----------
    basis : SineBasis
    n_points : int, optional
        Midpoint nodes (default ``3N // 2 + 1``, the smallest exact rule).
    """

    def __init__(self, basis, n_points=None):
        if not isinstance(basis, SineBasis):
            raise TypeError(f"`basis` must be a SineBasis, got {type(basis).__name__}")
        n = basis.size
        n_exact = 3 * n // 2 + 1
        n_points = n_exact if n_points is None else check_int("n_points", n_points, minimum=1)
        if n_points < n_exact:
            raise ValueError(f"`n_points` must be >= 3N // 2 + 1 = {n_exact} for exactness")
        x = (np.arange(n_points) + 0.5) / n_points
        self._n = n
        self._B = basis.evaluate(x)  # (n_points, N)
        self._Bd = basis.evaluate(x, 1)
        self._BtW = self._B.T / n_points  # quadrature weights 1/n folded in

    @property
    def size(self):
        """State size N."""
        return self._n

    def apply(self, X, Y):
        """:math:`A_{ijk} X_{jm} Y_{km}` column by column.

        Parameters
        ----------
        X, Y : (N, m) ndarray

        Returns
        -------
        (N, m) ndarray
        """
        return self._BtW @ ((self._B @ X) * (self._Bd @ Y))

    def matrix(self, x):
        """:math:`S(x)_{ij} = (A_{ijk} + A_{ikj}) x_k`, the Jacobian of :math:`q(x, x)`.

        Parameters
        ----------
        x : (N,) ndarray

        Returns
        -------
        (N, N) ndarray
        """
        w = self._B @ x
        wx = self._Bd @ x
        return self._BtW @ (wx[:, None] * self._B + w[:, None] * self._Bd)


class BurgersModel:
    """The discretized Burgers model of Section 3.1 as a :class:`GalerkinSystem`.

    Parameters
    ----------
    n_modes : int
        Number of sine modes N (paper: 50).
    n_steps : int
        Backward-Euler steps :math:`\\mathcal P` (paper: 100).
    T : float
        Final time (paper: 2).
    sensors : (C,) array_like
        Sensor positions in (0, 1) (paper: C = 4 evenly spaced, 0.2, 0.4, 0.6, 0.8).
    hat_half_width : float, optional
        Half-width a of the hat constraint forces; default the smallest sensor spacing
        (0.2 for the paper's sensors). The paper does not state it.
    newton_tol : float
        Newton tolerance on :math:`\\|R\\|_2` per step (paper: 1e-6).
    newton_maxiter : int
        Newton iterations per step before the step is declared failed.
    viscosity_chaos : ChaosBasis, optional
        Stochastic basis for a random log-viscosity; ``None`` (default) for the
        deterministic model (P = 1).
    viscosity_spread : float
        Width :math:`\\delta` of the uniform log-viscosity,
        :math:`\\epsilon_1(\\omega) = \\epsilon_1 + \\delta(\\omega - 1/2)`; used only with
        ``viscosity_chaos``.
    initial_state : {"projection", "paper"}
        ``"projection"`` (default): the L2 projection :math:`\\theta_0 = M^{-1}\\int u_0 f`,
        whose field is :math:`u_0` itself. ``"paper"``: the formula printed after
        Eq. backward_euler, :math:`\\theta_{0,i} = \\int u_0 f_i`, which for the sine basis
        (:math:`M = I/2`) starts from :math:`u_0/2`; kept to study its effect.
    viscosity_cells : int, optional
        A spatially varying viscosity, piecewise constant on this many equal cells:
        :math:`\\nu(x) = 10^{-\\epsilon_c}` on cell ``c``, so ``eps = (eps_0, ...,
        eps_{n-1}, source)`` and ``n_eps = viscosity_cells + 1`` (a many-parameter
        calibration for adjoint gradients). ``None`` (default): the paper's uniform
        viscosity.

    Attributes
    ----------
    basis : SineBasis
    M, K : (N, N) ndarray
    A : (N, N, N) ndarray
    F0 : (N,) ndarray
        :math:`\\int \\sin(2\\pi x) f_i`, so that :math:`F(t) = \\sin(2\\pi t) F_0`.
    Gamma : (N, C) ndarray
    M_obs : (C, N) ndarray
    theta0 : (N,) ndarray
        L2 projection :math:`M^{-1}\\int u_0 f` of the initial condition.
    system : GalerkinSystem
        ``n_eps = 2``: ``eps = (eps1, eps2)``.
    dt : float
    times : (n_steps + 1,) ndarray
    """

    n_eps = 2

    def __init__(
        self,
        n_modes=50,
        n_steps=100,
        T=2.0,
        sensors=PAPER_SENSORS,
        hat_half_width=None,
        newton_tol=1e-10,
        newton_maxiter=30,
        viscosity_chaos=None,
        viscosity_spread=0.0,
        initial_state="projection",
        viscosity_cells=None,
    ):
        self.n_modes = check_int("n_modes", n_modes, minimum=1)
        self.n_steps = check_int("n_steps", n_steps, minimum=1)
        self.T = check_positive("T", T)
        self.sensors = as_finite_array("sensors", sensors, ndim=1)
        if self.sensors.size < 1:
            raise ValueError("`sensors` must hold at least one position")
        if np.any((self.sensors <= 0.0) | (self.sensors >= 1.0)):
            raise ValueError("`sensors` must lie strictly inside (0, 1)")
        if np.unique(self.sensors).size != self.sensors.size:
            raise ValueError("`sensors` must be distinct positions")
        if hat_half_width is None:
            pts = np.sort(np.concatenate([[0.0, 1.0], self.sensors]))
            hat_half_width = float(np.round(np.min(np.diff(pts)), 12))
        self.hat_half_width = check_positive("hat_half_width", hat_half_width)
        self.newton_tol = check_positive("newton_tol", newton_tol)
        self.newton_maxiter = check_int("newton_maxiter", newton_maxiter, minimum=1)
        self.viscosity_spread = float(viscosity_spread)
        if not np.isfinite(self.viscosity_spread) or self.viscosity_spread < 0:
            raise ValueError(f"`viscosity_spread` must be finite and >= 0, got {viscosity_spread}")

        basis = SineBasis(self.n_modes)
        self.basis = basis
        self.M = mass(basis)
        self.K = stiffness(basis)
        self.F0 = load(basis, source_shape)
        self.initial_state = check_choice("initial_state", initial_state, INITIAL_STATES)
        if self.initial_state == "projection":
            self.theta0 = project(basis, initial_condition)
        else:
            self.theta0 = load(basis, initial_condition)
        self.Gamma = hat_forces(basis, self.sensors, self.hat_half_width)
        self.M_obs = sensor_matrix(basis, self.sensors)
        self.dt = self.T / self.n_steps
        self.times = self.dt * np.arange(self.n_steps + 1)
        self.chaos = viscosity_chaos
        self.viscosity_cells = (
            None
            if viscosity_cells is None
            else check_int("viscosity_cells", viscosity_cells, minimum=1)
        )
        if self.viscosity_cells is not None:
            self.n_eps = self.viscosity_cells + 1
        self._A = None
        self.system = self._build_system()

    def _build_system(self):
        """Assemble :math:`R = A:\\theta\\theta + 10^{-\\epsilon_1}K\\theta - \\epsilon_2 F(t)`."""
        G = None
        if self.chaos is not None:
            from ..chaos import weighted_gram

            d = self.viscosity_spread
            # enough nodes for the analytic weight 10^(-d (w - 1/2)) at any order used here
            n_points = self.chaos.order + 12
            G = weighted_gram(
                self.chaos, lambda w: 10.0 ** (-d * (w[:, 0] - 0.5)), n_points=n_points
            )
        F0 = self.F0
        terms = [QuadraticTerm(ConvectionForm(self.basis), 1.0, name="convection")]
        if self.viscosity_cells is None:
            terms.append(
                LinearTerm(self.K, Coefficient.power10(0, sign=-1.0), G=G, name="diffusion")
            )
        else:
            edges = np.linspace(0.0, 1.0, self.viscosity_cells + 1)
            for c in range(self.viscosity_cells):
                lo, hi = edges[c], edges[c + 1]
                Kc = stiffness(
                    self.basis,
                    weight=lambda x, lo=lo, hi=hi: ((x >= lo) & (x < hi)).astype(float),
                    breakpoints=edges[1:-1],
                )
                terms.append(
                    LinearTerm(Kc, Coefficient.power10(c, sign=-1.0), G=G, name=f"diffusion {c}")
                )
        source = Coefficient.parameter(self.n_eps - 1)
        terms.append(LoadTerm.scaled(lambda t: source_time(t) * F0, source, name="source"))
        return GalerkinSystem(
            terms, n_eps=self.n_eps, basis=self.chaos, Gamma=self.Gamma, M=self.M, name="burgers"
        )

    @property
    def A(self):
        """Dense :math:`A_{ijk} = \\int f_i f_j f_k'`, ``(N, N, N)`` (built on first use;
        the system itself uses the equivalent :class:`ConvectionForm`)."""
        if self._A is None:
            self._A = triple(self.basis, derivatives=(0, 0, 1))
        return self._A

    # -- forward solves ------------------------------------------------------------------
    @property
    def Theta0(self):
        """Initial chaos state ``(N, P)``: the projected :math:`u_0` in the mean mode."""
        Th = self.system.zeros()
        Th[:, 0] = self.theta0
        return Th

    def solve(self, eps, *, data=None, sensitivities=False, strict=False):
        """March the model from :math:`u_0` over ``[0, T]`` by backward Euler.

        Parameters
        ----------
        eps : (2,) array_like
            :math:`(\\epsilon_1, \\epsilon_2)`.
        data : (n_steps + 1, C) array_like, optional
            Sensor data; when given, the constraint forces :math:`\\lambda_t` enforce
            :math:`\\mathcal M\\,\\mathbb E[\\theta_t] = v_t` at every step (Eq. ecfm_solve).
        sensitivities : bool
            Also integrate the sensitivities (Eqs. discrete_sens, discrete_sens_ecfm).
        strict : bool
            Raise :class:`ecfm_uq.errors.ConvergenceError` on a failed step.

        Returns
        -------
        Trajectory
        """
        constraint = None if data is None else (self.M_obs, data)
        return march(
            self.system,
            eps,
            self.Theta0,
            self.dt,
            self.n_steps,
            constraint=constraint,
            sensitivities=sensitivities,
            tol=self.newton_tol,
            maxiter=self.newton_maxiter,
            strict=strict,
        )

    def measure(self, trajectory):
        """Sensor readings of the mean state, :math:`\\mathcal M\\,\\Theta_t\\mathbb E[\\Psi]`.

        Returns
        -------
        (n_times, C) ndarray
        """
        return trajectory.Theta @ self.system.E1 @ self.M_obs.T

    def true_data(self, true_eps=PAPER_TRUE_EPS):
        """Noiseless data from the same discretization at ``true_eps``.

        Returns
        -------
        V : (n_steps + 1, C) ndarray
            Row ``t`` is the mean sensor reading at time ``t * dt`` (row 0 is the initial
            state).

        Raises
        ------
        ConvergenceError
            If the forward solve fails.
        """
        return self.measure(self.solve(true_eps, strict=True))

    def field(self, Theta, x):
        """Mean field :math:`\\mathbb E[w](x)` for states ``Theta``.

        Parameters
        ----------
        Theta : (..., N, P) array_like
        x : (m,) array_like

        Returns
        -------
        (..., m) ndarray
        """
        return (np.asarray(Theta) @ self.system.E1) @ self.basis.evaluate(x).T

    def settings(self):
        """The model settings as a plain dict (for result files)."""
        return {
            "n_modes": self.n_modes,
            "n_steps": self.n_steps,
            "T": self.T,
            "dt": self.dt,
            "sensors": self.sensors.tolist(),
            "hat_half_width": self.hat_half_width,
            "newton_tol": self.newton_tol,
            "newton_maxiter": self.newton_maxiter,
            "chaos_order": None if self.chaos is None else int(self.chaos.order),
            "viscosity_spread": self.viscosity_spread,
            "initial_state": self.initial_state,
        }
