"""Stochastic axially loaded Euler-Bernoulli beam (paper Section 3.3, Eqs. random_govern,
pce, stats).

The beam obeys

.. math::

    (H(x,\\omega)\\,u'')'' + \\beta u'' = p, \\quad x \\in [0, 1], \\qquad
    u(0) = u''(0) = u'(1) = (H u'')'(1) = 0,

with the axial load :math:`\\beta` modelled by the parameter :math:`\\epsilon`. Its weak
form (Section 3.3, after two integrations by parts) discretized with the beam modes
:math:`f_i = \\sin((2i-1)\\pi x/2)` is Eq. random_govern,

.. math::

    (K^B(\\omega) - \\epsilon K^G - K^{BC})\\,\\theta - F - \\Gamma\\lambda = 0,

    K^B_{ij} = \\int_0^1 H f_i'' f_j'', \\quad K^G_{ij} = \\int_0^1 f_i' f_j', \\quad
    K^{BC}_{ij} = H(1)\\, f_i'(1)\\, f_j''(1), \\quad F_i = \\int_0^1 p f_i,

where in :math:`K^{BC}` the row index ``i`` belongs to the test function (the paper's
boundary term :math:`H(1) w''(1)\\,\\delta w'(1)`). The beam modes have
:math:`f_i'(1) = 0`, so :math:`K^{BC}` vanishes up to round-off (about 4e-12 for
``N = 6``); it is computed and kept anyway so the operator is the paper's.

**Stiffness (typo fix, SPEC).** The paper prints :math:`H = H_0(2\\omega|x - 1/2| - \\omega)`,
which is never positive. We use

.. math:: H(x,\\omega) = H_0\\,(1 - \\delta\\,\\omega\\,(1 - 2|x - 1/2|)),

deterministic at the ends, softest at the centre, so :math:`K^B(\\omega) = K_0 -
\\delta\\omega K_1` is affine in the germ (operators integrated with a breakpoint at 1/2),
and :math:`\\delta` is found by root-finding (:func:`calibrate_delta`) so that the worst-case
(:math:`\\omega = 1`) buckling load of the 15-mode reference model is
:math:`\\beta_{crit} = 2.24` (giving :math:`\\delta \\approx 0.17804`).

**Stochastic Galerkin (Eq. pce).** With :math:`\\omega \\sim U(0,1)` and the orthonormal
shifted Legendre chaos :math:`\\Psi_k` (same span as the paper's unnormalised
:math:`P_n(2\\omega - 1)`, so the same solution), :math:`\\theta(\\omega) = \\Theta\\Psi(\\omega)`
solves

.. math::

    (K_0 - K^{BC})\\Theta\\,\\mathbb E[\\Psi\\Psi^T] - \\delta K_1\\Theta\\,\\mathbb E[\\omega\\Psi\\Psi^T]
    - \\epsilon K^G\\Theta\\,\\mathbb E[\\Psi\\Psi^T] - (F + \\Gamma\\lambda)\\,\\mathbb E[\\Psi^T] = 0,

and the sensor statistics follow Eq. stats. A load at or above buckling for any
:math:`\\omega \\in [0, 1]` makes the operator singular or indefinite; it raises
:class:`~ecfm_uq.errors.SingularSystemError` instead of returning a meaningless PCE.
"""

from __future__ import annotations

import functools

import numpy as np
import scipy.linalg as sla
from scipy.optimize import brentq

from .._validation import as_finite_array, check_choice, check_int, check_positive, check_real
from ..chaos import ChaosBasis, weighted_gram
from ..errors import SingularSystemError
from ..spectral import BeamBasis, gaussian_forces, gram, hat_forces, load, sensor_matrix
from ..system import Coefficient, GalerkinSystem, LinearTerm, LoadTerm, solve_steady

__all__ = [
    "BeamModel",
    "BeamOperators",
    "beam_operators",
    "buckling_load",
    "calibrate_delta",
    "deterministic_response",
]

PAPER_BETA_CRIT = 2.24
DEFAULT_SENSORS = (0.2, 0.4, 0.6, 0.8, 1.0)
FORCE_SHAPES = ("hat", "gaussian")


def _check_eps(eps):
    """The axial load as a float; a 1-element array (the system's eps vector) is accepted."""
    if isinstance(eps, np.ndarray | list | tuple):
        arr = as_finite_array("eps", eps)
        if arr.size != 1:
            raise ValueError(f"`eps` must be a scalar axial load, got shape {arr.shape}")
        return float(arr.reshape(-1)[0])
    return check_real("eps", eps)


def _check_omega(omega):
    omega = check_real("omega", omega)
    if not 0.0 <= omega <= 1.0:
        raise ValueError(f"`omega` must lie in the germ's support [0, 1], got {omega}")
    return omega


def _check_delta(delta):
    delta = check_real("delta", delta)
    if delta >= 1.0:
        raise ValueError(
            f"`delta` must be < 1 so that H(x, omega) = H0 (1 - delta omega (1 - 2|x - 1/2|)) "
            f"stays positive for omega in [0, 1], got {delta}"
        )
    return delta


class BeamOperators:
    """Spatial operators of the beam for one basis size (paper Eq. random_govern).

    Parameters
    ----------
    n_basis : int
        Number of beam modes N.
    H0 : float
        End stiffness :math:`H_0 > 0`.
    p : float
        Uniform bending load.

    Attributes
    ----------
    basis : BeamBasis
    K0 : (N, N) ndarray
        :math:`H_0 \\int f_i'' f_j''`.
    K1 : (N, N) ndarray
        :math:`H_0 \\int (1 - 2|x - 1/2|) f_i'' f_j''`, so that
        :math:`K^B(\\omega) = K_0 - \\delta\\omega K_1`.
    KG : (N, N) ndarray
        Geometric stiffness :math:`\\int f_i' f_j'` (diagonal, :math:`k_i^2/2`).
    KBC : (N, N) ndarray
        :math:`H_0 f_i'(1) f_j''(1)` (zero to round-off for the beam modes).
    F : (N,) ndarray
        :math:`\\int p f_i`.
    """

    def __init__(self, n_basis, H0=1.0, p=100.0):
        n_basis = check_int("n_basis", n_basis, minimum=1)
        self.H0 = check_positive("H0", H0)
        self.p = check_real("p", p)
        self.basis = BeamBasis(n_basis)
        b = self.basis
        tent = lambda x: 1.0 - 2.0 * np.abs(x - 0.5)
        self.K0 = self.H0 * gram(b, derivatives=(2, 2), breakpoints=(0.5,))
        self.K1 = self.H0 * gram(b, derivatives=(2, 2), weight=tent, breakpoints=(0.5,))
        self.KG = gram(b, derivatives=(1, 1))
        one = np.ones(1)
        # row i: test function f_i'(1); column j: trial function f_j''(1)
        self.KBC = self.H0 * np.outer(b.evaluate(one, 1)[0], b.evaluate(one, 2)[0])
        self.F = load(b, lambda x: np.full_like(x, self.p))
        for a in (self.K0, self.K1, self.KG, self.KBC, self.F):
            a.setflags(write=False)  # shared through the beam_operators cache

    @property
    def size(self):
        """Number of modes N."""
        return self.basis.size

    def stiffness(self, omega, delta):
        """:math:`K^B(\\omega) - K^{BC}` of shape (N, N)."""
        return self.K0 - delta * omega * self.K1 - self.KBC

    def buckling_load(self, omega, delta):
        """Smallest generalized eigenvalue of :math:`(K^B(\\omega) - K^{BC}) v = \\beta K^G v`."""
        ev = sla.eigvals(self.stiffness(omega, delta), self.KG)
        real = ev.real[np.abs(ev.imag) <= 1e-9 * np.abs(ev)]
        if real.size == 0:
            raise SingularSystemError(
                f"no real buckling mode at omega={omega}, delta={delta}: the stiffness "
                "operator is not symmetric-definite"
            )
        return float(real.min())


@functools.lru_cache(maxsize=16)
def beam_operators(n_basis, H0=1.0, p=100.0):
    """Cached :class:`BeamOperators` (treat the arrays as read-only)."""
    return BeamOperators(n_basis, H0, p)


def buckling_load(delta, omega=1.0, n_basis=15, H0=1.0):
    """Buckling load :math:`\\beta_{crit}(\\omega)` of the ``n_basis``-mode beam.

    Parameters
    ----------
    delta : float
        Softening amplitude, ``delta < 1``.
    omega : float
        Germ value in [0, 1].
    n_basis : int
    H0 : float

    Returns
    -------
    float
        Smallest :math:`\\beta` with :math:`(K^B(\\omega) - K^{BC} - \\beta K^G)` singular.
    """
    delta = _check_delta(delta)
    omega = _check_omega(omega)
    return beam_operators(
        check_int("n_basis", n_basis, minimum=1), check_positive("H0", H0)
    ).buckling_load(omega, delta)


def calibrate_delta(beta_crit=PAPER_BETA_CRIT, n_basis=15, H0=1.0):
    """Softening amplitude :math:`\\delta` with worst-case buckling load ``beta_crit``.

    Solves :math:`\\beta_{crit}(\\omega = 1; \\delta) = ` ``beta_crit`` by Brent's method
    on :math:`\\delta \\in [0, 1)`, with the ``n_basis``-mode model (the paper's 15-mode
    reference by default). This replaces the paper's misprinted stiffness (module
    docstring); with the defaults :math:`\\delta \\approx 0.178035`.

    Parameters
    ----------
    beta_crit : float
        Target buckling load at :math:`\\omega = 1`; must lie strictly between the load
        of a nearly fully softened centre and :math:`\\beta_{crit}(\\delta = 0) = \\pi^2 H_0/4`.
    n_basis : int
    H0 : float

    Returns
    -------
    float
    """
    target = check_positive("beta_crit", beta_crit)
    n_basis = check_int("n_basis", n_basis, minimum=1)
    H0 = check_positive("H0", H0)
    return _calibrate(target, n_basis, H0)


@functools.lru_cache(maxsize=16)
def _calibrate(target, n_basis, H0):
    ops = beam_operators(n_basis, H0)
    hi = 1.0 - 1e-6
    b_lo, b_hi = ops.buckling_load(1.0, 0.0), ops.buckling_load(1.0, hi)
    if not b_hi < target < b_lo:
        raise ValueError(
            f"`beta_crit` must lie in ({b_hi:.6g}, {b_lo:.6g}) for H0={H0} with {n_basis} modes "
            f"(the range reachable with 0 <= delta < 1), got {target}"
        )
    return float(brentq(lambda d: ops.buckling_load(1.0, d) - target, 0.0, hi, xtol=1e-14))


@functools.lru_cache(maxsize=32)
def _constraint_forces(n_basis, sensors, shape, width):
    """Gamma (N, C), cached: its composite quadrature dominates building a model."""
    basis = BeamBasis(n_basis)
    if shape == "hat":
        Gamma = hat_forces(basis, np.array(sensors), width)
    else:
        Gamma = gaussian_forces(basis, np.array(sensors), 0.5 / width**2)
    Gamma.setflags(write=False)
    return Gamma


def deterministic_response(omega, A0, A1, F, Obs):
    """Observed deterministic solution :math:`O\\,(A_0 + \\omega A_1)^{-1} F` at one germ value.

    Module-level (hence picklable) kernel for Monte Carlo over deterministic solves; build
    it with :meth:`BeamModel.response_function`.

    Parameters
    ----------
    omega : float
    A0, A1 : (N, N) ndarray
    F : (N,) ndarray
    Obs : (m, N) ndarray

    Returns
    -------
    (m,) ndarray
    """
    w = float(np.asarray(omega).reshape(-1)[0])
    return Obs @ np.linalg.solve(A0 + w * A1, F)


class BeamModel:
    """The stochastic beam of paper Section 3.3 as a :class:`GalerkinSystem`.

    Parameters
    ----------
    n_basis : int
        Number of beam modes N (paper: 6).
    order : int
        Chaos order; ``order + 1`` terms (paper: M = 6, order 5).
    delta : float, optional
        Softening amplitude; ``None`` calibrates it with :func:`calibrate_delta`
        (worst-case buckling load 2.24 of the 15-mode model).
    H0 : float
        End stiffness (paper: 1).
    p : float
        Uniform bending load (paper: 100).
    sensors : (C,) array_like
        Sensor positions in [0, 1] (default 0.2, 0.4, ..., 1.0; the paper gives C = 5
        but not where).
    force_shape : {"hat", "gaussian"}
        Constraint-force shape centred on each sensor (not given in the paper). ``"hat"``:
        unit-height hat of half-width ``force_width`` (cut at the domain ends, so the
        force at x = 1 is a half hat); ``"gaussian"``: normal density with standard
        deviation ``force_width``.
    force_width : float

    Attributes
    ----------
    delta : float
    basis : BeamBasis
    chaos : ChaosBasis
    ops : BeamOperators
    system : GalerkinSystem
        ``n_eps = 1`` (the axial load), state :math:`\\Theta` of shape (N, P).
    sensors : (C,) ndarray
    M_obs : (C, N) ndarray
        :math:`\\mathcal M_{ij} = f_j(x_i)`.
    Gamma : (N, C) ndarray
        :math:`\\Gamma_{ij} = \\int f_i\\,\\Gamma(x - x_j)`.
    """

    def __init__(
        self,
        n_basis=6,
        order=5,
        delta=None,
        H0=1.0,
        p=100.0,
        sensors=DEFAULT_SENSORS,
        force_shape="hat",
        force_width=0.2,
    ):
        self.ops = beam_operators(
            check_int("n_basis", n_basis, minimum=1), check_positive("H0", H0), check_real("p", p)
        )
        self.H0, self.p = self.ops.H0, self.ops.p
        self.delta = calibrate_delta(H0=self.H0) if delta is None else _check_delta(delta)
        self.basis = self.ops.basis
        self.chaos = ChaosBasis(check_int("order", order, minimum=0))
        self.sensors = as_finite_array("sensors", sensors, ndim=1)
        if self.sensors.size == 0:
            raise ValueError("`sensors` must hold at least one position in [0, 1]")
        self.M_obs = sensor_matrix(self.basis, self.sensors)
        if not isinstance(force_shape, str):
            raise TypeError(
                f"`force_shape` must be one of {list(FORCE_SHAPES)}, got {force_shape!r}"
            )
        self.force_shape = check_choice("force_shape", force_shape, FORCE_SHAPES)
        self.force_width = check_positive("force_width", force_width)
        self.Gamma = _constraint_forces(
            self.N, tuple(self.sensors.tolist()), self.force_shape, self.force_width
        )
        # E[omega Psi_k Psi_l]: exact with the default Gauss rule (degree 2 order + 1)
        self.G_omega = weighted_gram(self.chaos, lambda w: w[:, 0])
        self.system = GalerkinSystem(
            [
                LinearTerm(self.ops.K0 - self.ops.KBC, name="bending K0 - K_BC"),
                LinearTerm(self.ops.K1, coef=-self.delta, G=self.G_omega, name="softening K1"),
                LinearTerm(self.ops.KG, Coefficient.parameter(0, scale=-1.0), name="geometric"),
                LoadTerm.constant(self.ops.F, name="bending load"),
            ],
            n_eps=1,
            basis=self.chaos,
            Gamma=self.Gamma,
            name="stochastic beam",
        )
        self._beta = {}

    def __repr__(self):
        return (
            f"BeamModel(N={self.N}, P={self.P}, delta={self.delta:.6g}, C={self.sensors.size}, "
            f"force_shape={self.force_shape!r})"
        )

    @property
    def N(self):
        """Number of beam modes."""
        return self.basis.size

    @property
    def P(self):
        """Number of chaos terms."""
        return self.chaos.size

    # -- buckling ----------------------------------------------------------------------
    def beta_crit(self, omega=1.0):
        """Buckling load of this N-mode model at the germ value ``omega``.

        Returns
        -------
        float
            Smallest :math:`\\beta` with :math:`K^B(\\omega) - K^{BC} - \\beta K^G` singular.
        """
        omega = _check_omega(omega)
        if omega not in self._beta:
            self._beta[omega] = self.ops.buckling_load(omega, self.delta)
        return self._beta[omega]

    @property
    def beta_min(self):
        """:math:`\\min_{\\omega\\in[0,1]} \\beta_{crit}(\\omega)`.

        :math:`\\beta_{crit}(\\omega) = \\min_v v^T K^B(\\omega) v / v^T K^G v` is a minimum of
        functions affine in :math:`\\omega`, hence concave, so the minimum over [0, 1] is
        at an end point (at :math:`\\omega = 1` for :math:`\\delta \\ge 0`).
        """
        return min(self.beta_crit(0.0), self.beta_crit(1.0))

    def check_load(self, eps):
        """Raise :class:`SingularSystemError` if ``eps`` buckles the beam for some omega.

        For :math:`\\epsilon < \\min_\\omega \\beta_{crit}(\\omega)` the operator
        :math:`K^B(\\omega) - \\epsilon K^G` is positive definite for every
        :math:`\\omega \\in [0, 1]`, and so is its stochastic Galerkin projection
        (Eq. pce); at or above it the PCE would be singular or meaningless.
        """
        eps = _check_eps(eps)
        if eps >= self.beta_min:
            raise SingularSystemError(
                f"axial load eps={eps:.6g} is at or above the buckling load "
                f"beta_crit={self.beta_min:.6g} (worst case over omega in [0, 1]) of the "
                f"{self.N}-mode beam: K_B(omega) - eps K_G is singular or indefinite; "
                f"use eps < {self.beta_min:.6g}"
            )
        return eps

    # -- solves ------------------------------------------------------------------------
    def solve(self, eps, lam=None, **solve_kw):
        """Stochastic Galerkin solve of Eq. pce.

        Parameters
        ----------
        eps : float
            Axial load (the model parameter).
        lam : (C,) array_like, optional
            Constraint forces (zero by default).
        **solve_kw
            Passed to :func:`~ecfm_uq.system.solve_steady` (``tol``, ``strict``, ...).

        Returns
        -------
        SteadySolution
            ``.Theta`` of shape (N, P); ``.eps_sensitivity()`` and ``.lam_sensitivity()``
            give Eq. stochastic_sens.
        """
        eps = self.check_load(eps)
        return solve_steady(self.system, np.array([eps]), lam, **solve_kw)

    def system_at(self, omega):
        """The deterministic (P = 1) system at a fixed germ value, same terms, ``basis=None``."""
        omega = _check_omega(omega)
        return GalerkinSystem(
            [
                LinearTerm(self.ops.K0 - self.ops.KBC),
                LinearTerm(self.ops.K1, coef=-self.delta * omega),
                LinearTerm(self.ops.KG, Coefficient.parameter(0, scale=-1.0)),
                LoadTerm.constant(self.ops.F),
            ],
            n_eps=1,
            Gamma=self.Gamma,
            name=f"beam at omega={omega:g}",
        )

    def _ops_for(self, n_basis):
        if n_basis is None:
            return self.ops
        return beam_operators(check_int("n_basis", n_basis, minimum=1), self.H0, self.p)

    def solve_deterministic(self, omega, eps, n_basis=None, lam=None):
        """Plain deterministic solve :math:`\\theta = (K^B(\\omega) - \\epsilon K^G - K^{BC})^{-1}(F + \\Gamma\\lambda)`.

        Parameters
        ----------
        omega : float
            Germ value in [0, 1].
        eps : float
            Axial load; must be below the buckling load at this ``omega``.
        n_basis : int, optional
            Number of modes N' (default: the model's N; the paper's reference uses 15).
        lam : (C,) array_like, optional
            Constraint forces; only with the model's own basis.

        Returns
        -------
        (N',) ndarray
        """
        omega = _check_omega(omega)
        eps = _check_eps(eps)
        ops = self._ops_for(n_basis)
        bc = ops.buckling_load(omega, self.delta)
        if eps >= bc:
            raise SingularSystemError(
                f"axial load eps={eps:.6g} is at or above the buckling load beta_crit={bc:.6g} "
                f"of the {ops.size}-mode beam at omega={omega:g}; use eps < {bc:.6g}"
            )
        rhs = ops.F.copy()
        if lam is not None:
            if ops is not self.ops:
                raise ValueError("`lam` needs the model's own basis; leave `n_basis` unset")
            rhs = rhs + self.Gamma @ as_finite_array("lam", lam, shape=(self.sensors.size,))
        return np.linalg.solve(ops.stiffness(omega, self.delta) - eps * ops.KG, rhs)

    def deterministic_displacement(self, omega, eps, x, n_basis=None):
        """Deterministic displacement :math:`u(x, \\omega)` on ``x`` for each ``omega``.

        Returns
        -------
        (len(x), len(omega)) ndarray
        """
        x = self._check_x(x)
        om = np.atleast_1d(as_finite_array("omega", omega))
        ops = self._ops_for(n_basis)
        F = ops.basis.evaluate(x)
        cols = [F @ self.solve_deterministic(float(w), eps, n_basis=n_basis) for w in om]
        return np.column_stack(cols)

    def response_function(self, eps, x=None):
        """A picklable function ``omega -> (C + len(x),)`` of deterministic solves.

        Returns ``functools.partial(deterministic_response, ...)`` measuring the sensors
        (first C entries) and the displacement at ``x`` (if given); used for Monte Carlo
        over deterministic solves (:mod:`ecfm_uq.mc`).
        """
        eps = self.check_load(eps)
        Obs = (
            self.M_obs
            if x is None
            else np.vstack([self.M_obs, self.basis.evaluate(self._check_x(x))])
        )
        return functools.partial(
            deterministic_response,
            A0=self.ops.K0 - self.ops.KBC - eps * self.ops.KG,
            A1=-self.delta * self.ops.K1,
            F=self.ops.F.copy(),
            Obs=Obs,
        )

    # -- evaluation and statistics -----------------------------------------------------
    @staticmethod
    def _check_x(x):
        x = np.atleast_1d(as_finite_array("x", x))
        if x.ndim != 1:
            raise ValueError(f"`x` must be 1-D, got shape {x.shape}")
        if np.any((x < 0) | (x > 1)):
            raise ValueError("`x` must lie in [0, 1]")
        return x

    def _check_Theta(self, Theta):
        return as_finite_array("Theta", Theta, shape=(self.N, self.P))

    def displacement(self, Theta, x, omega):
        """PCE displacement :math:`w(x, \\omega) = f(x)^T \\Theta \\Psi(\\omega)`.

        Parameters
        ----------
        Theta : (N, P) array_like
        x : (m,) array_like
        omega : (n,) array_like

        Returns
        -------
        (m, n) ndarray
        """
        Theta = self._check_Theta(Theta)
        x = self._check_x(x)
        Psi = self.chaos.evaluate(np.atleast_1d(as_finite_array("omega", omega)))
        return self.basis.evaluate(x) @ Theta @ Psi.T

    def sensor_samples(self, Theta, omega):
        """Measurements :math:`v(\\omega) = \\mathcal M\\,\\Theta\\,\\Psi(\\omega)`, shape (C, n)."""
        Theta = self._check_Theta(Theta)
        Psi = self.chaos.evaluate(np.atleast_1d(as_finite_array("omega", omega)))
        return self.M_obs @ Theta @ Psi.T

    def sensor_moments(self, Theta):
        """Mean and variance at the sensors from the PCE (Eq. stats).

        Returns
        -------
        mu : (C,) ndarray
        var : (C,) ndarray
        """
        return self.moments(Theta, self.M_obs)

    def displacement_moments(self, Theta, x):
        """Mean and variance of :math:`w(x, \\omega)` on ``x`` (Eq. stats with
        :math:`\\mathcal M` replaced by :math:`f_j(x_i)`), each (len(x),)."""
        return self.moments(Theta, self.basis.evaluate(self._check_x(x)))

    def moments(self, Theta, Obs):
        """Mean and variance of :math:`O\\,\\Theta\\,\\Psi` for an observation matrix ``Obs``."""
        Theta = self._check_Theta(Theta)
        V = Obs @ Theta
        E1, E2 = self.system.E1, self.system.E2
        mu = V @ E1
        # Eq. stats, with mu^2 = V_k V_q E[Psi_k] E[Psi_q] moved inside the sum: the same
        # value without the cancellation of E[v^2] - mu^2 when mu^2 >> var
        var = np.einsum("ik,kq,iq->i", V, E2 - np.outer(E1, E1), V)
        return mu, np.maximum(var, 0.0)

    def sample_data(self, eps=1.0, n_replicates=25, rng=None):
        """Synthetic measurements as in the paper: D germ draws measured at all sensors.

        Each replicate is one draw :math:`\\omega_j \\sim U(0,1)` measured by the PCE
        solved at ``eps`` with :math:`\\lambda = 0`:
        :math:`v_{ij} = \\mathcal M_{ik}\\Theta_{kl}\\Psi_l(\\omega_j)`.

        Parameters
        ----------
        eps : float
            True axial load (paper: 1).
        n_replicates : int
            D (paper: 25).
        rng : None, int or numpy.random.Generator
            Seed or generator (``None``: fresh entropy, not reproducible).

        Returns
        -------
        (C, D) ndarray
        """
        D = check_int("n_replicates", n_replicates, minimum=1)
        gen = np.random.default_rng(rng)
        sol = self.solve(eps, strict=True)
        return self.sensor_samples(sol.Theta, gen.random(D))
