"""Steady heat conduction with unknown boundary data or unknown domain geometry (paper
Section 4, "The cases of parametric boundary conditions and domain geometry").

The paper only derives these two cases; here they are built as working systems
:math:`R(\\theta; \\epsilon, \\lambda) = K(\\epsilon)\\theta - F(\\epsilon) - \\Gamma\\lambda`
for the steady standard and ECFM inverse layer (:func:`ecfm_uq.inverse.fit` of a
:class:`~ecfm_uq.inverse.SteadyProblem`).
The model is :math:`\\nabla^2 w + s = 0` in every case.

Boundary case (:func:`boundary_problem`)
    The rod :math:`[0, 1]` with Dirichlet data :math:`w(0) = g = \\epsilon_1` and Neumann
    data :math:`w'(1) = h = \\epsilon_2`. Following the paper, the Dirichlet value is
    built into the discretization by a lift,
    :math:`\\hat w = \\sum_i \\theta_i f_i(x) + g(x;\\epsilon)` with
    :math:`g(x;\\epsilon) = \\epsilon_1 (1 - x)` and the beam modes
    :math:`f_i = \\sin((2i-1)\\pi x/2)` (:math:`f_i(0) = 0`, :math:`f_i(1) = \\pm 1`), and
    the Galerkin weak form integrated by parts gives the paper's

    .. math::

        \\Big(\\int_0^1 f_i' f_j'\\Big)\\theta_i = \\int_0^1 s f_j + h f_j(1)
            - \\int_0^1 g' f_j' ,

    i.e. :math:`K\\theta = F(\\epsilon)`: the parameters enter :math:`F` only.
    The sensors see :math:`\\hat w`, which contains the lift. So that the measurement is
    a fixed linear map :math:`\\mathcal M` of the state (as the inverse layer requires),
    the lift amplitude :math:`a` is appended to the state with the trivial equation
    :math:`a - \\epsilon_1 = 0`. Eliminating :math:`a` gives back exactly the paper's
    system; the constraint forces act on the heat equation rows only.

Geometry case, interval (:func:`interval_problem`)
    :math:`\\Omega(\\epsilon) = [0, L]`, :math:`L = \\epsilon_1`, :math:`w(0) = w(L) = 0`,
    mapped to :math:`\\xi = x/L \\in [0, 1]` with the sine basis :math:`f_i(\\xi)`:

    .. math::

        K(L) = \\frac{1}{L} \\int_0^1 f_i' f_j'\\,d\\xi, \\qquad
        F(L) = L \\int_0^1 s(L\\xi) f_j(\\xi)\\,d\\xi .

Geometry case, rectangle (:func:`rectangle_problem`)
    :math:`\\Omega(\\epsilon) = [0, a]\\times[0, b]`, :math:`(a, b) = (\\epsilon_1,
    \\epsilon_2)`, mapped to the unit square with the tensor sine basis:

    .. math::

        K(\\epsilon) = \\frac{b}{a} K_x\\otimes M_y + \\frac{a}{b} M_x\\otimes K_y, \\qquad
        F(\\epsilon) = ab \\int\\!\\!\\int s(a\\xi, b\\eta) f(\\xi, \\eta)\\,d\\xi\\,d\\eta .

    Both are the paper's :math:`\\int_{\\Omega(\\epsilon)} \\nabla f_i\\cdot\\nabla f_j`
    and :math:`\\int_{\\Omega(\\epsilon)} s f_j` after the change of variables; their
    derivatives in :math:`\\epsilon` are analytic (chain rule through :math:`s`).

Choices the paper leaves open (also in ``docs/heat.md``):

* Sensors of the geometry cases sit at fixed *reference* fractions :math:`\\xi_c` of the
  unknown domain (sensors that move with the boundary), so :math:`\\mathcal M` does not
  depend on :math:`\\epsilon`. Sensors at fixed physical positions would make
  :math:`\\mathcal M` depend on :math:`\\epsilon`, which the steady inverse layer does not
  support.
* Constraint-force shapes are fixed in reference coordinates and scaled by the inverse
  Jacobian, :math:`\\Gamma_j(x) = \\phi_j(\\xi(x)) / |\\partial x/\\partial\\xi|`, so that
  :math:`\\Gamma_{ij} = \\int_{\\Omega(\\epsilon)} f_i\\Gamma_j\\,dx = \\int f_i\\phi_j\\,d\\xi`
  does not depend on :math:`\\epsilon` and :math:`\\lambda_j` is the total heat injected
  by force :math:`j` (per unit :math:`\\int\\phi_j`) whatever the domain size. 1-D shapes
  are hats of half-width equal to the sensor spacing; 2-D shapes are the RBFs of
  Section 3.2, :math:`(\\omega/\\pi)e^{-\\omega\\|\\xi - \\xi_j\\|^2}`.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass, field

import numpy as np

from .._validation import as_finite_array, check_int, check_positive
from ..spectral import (
    BeamBasis,
    SineBasis,
    TensorBasis2D,
    composite_gauss,
    hat_forces,
    load,
    mass,
    rbf_forces,
    sensor_matrix,
    stiffness,
)
from ..system import Coefficient, GalerkinSystem, LinearTerm, LoadTerm, solve_steady

__all__ = [
    "HeatProblem",
    "boundary_closed_form",
    "boundary_problem",
    "gaussian_source",
    "interval_closed_form",
    "interval_problem",
    "rectangle_problem",
    "uniform_sensors",
]


# --------------------------------------------------------------------------------------
# the problem object
# --------------------------------------------------------------------------------------
@dataclass
class HeatProblem:
    """A discretized heat-conduction model ready for :func:`ecfm_uq.inverse.fit`.

    Fit it as ``fit(SteadyProblem(heat.system, heat.M_obs, v), eps0, formulation=...)``.

    Attributes
    ----------
    system : GalerkinSystem
        :math:`R(\\theta; \\epsilon, \\lambda) = K(\\epsilon)\\theta - F(\\epsilon) -
        \\Gamma\\lambda` (deterministic, ``P = 1``).
    M_obs : (C, N) ndarray
        Measurement operator on the state (fixed; see the module notes).
    sensors : (C,) or (C, 2) ndarray
        Sensor positions in reference coordinates (the unit interval or square).
    kind : {"boundary", "interval", "rectangle"}
    eps_names : tuple of str
        Names of the parameters, in order.
    bounds : list of (float or None, float or None)
        Physical range of each parameter, for bounded optimizers (a length must stay
        positive).
    centers : (C,) or (C, 2) ndarray
        Centres of the constraint-force shapes (reference coordinates).
    force_width : float
        Hat half-width (1-D) or RBF :math:`\\omega` (2-D).
    """

    system: GalerkinSystem
    M_obs: np.ndarray
    sensors: np.ndarray
    kind: str
    eps_names: tuple
    bounds: list
    centers: np.ndarray
    force_width: float
    _basis: object = field(repr=False, default=None)
    _positive: bool = field(repr=False, default=False)

    # -- parameters ------------------------------------------------------------------
    def check_eps(self, eps):
        """Validate ``eps`` (finite, right length; positive sizes for geometry cases)."""
        eps = self.system.check_eps(eps)
        if self._positive:
            _check_sizes(eps)
        return eps

    @property
    def n_eps(self):
        return self.system.n_eps

    # -- forward map -----------------------------------------------------------------
    def solve(self, eps, lam=None):
        """State :math:`\\theta(\\epsilon, \\lambda)`, shape (N,), by a strict steady solve."""
        eps = self.check_eps(eps)
        return solve_steady(self.system, eps, lam, strict=True).Theta[:, 0]

    def measure(self, eps, lam=None):
        """Noise-free sensor readings :math:`v = \\mathcal M\\theta(\\epsilon)`, shape (C,)."""
        return self.M_obs @ self.solve(eps, lam)

    def operators(self, eps):
        """:math:`K(\\epsilon)` (N, N) and :math:`F(\\epsilon)` (N,) of the residual.

        Read off the system: :math:`F = -R(0)` and :math:`K = \\partial R/\\partial\\theta`.
        """
        eps = self.check_eps(eps)
        zero = self.system.zeros()
        return self.system.jacobian(zero, eps), -self.system.residual(zero, eps)[:, 0]

    # -- fields on points --------------------------------------------------------------
    def field(self, theta, points):
        """Temperature :math:`\\hat w` at reference points.

        Parameters
        ----------
        theta : (N,) array_like
            State (for the boundary case it includes the lift amplitude).
        points : (m,) or (m, 2) array_like
            Reference coordinates in the unit interval or square; physical coordinates
            are :math:`x = \\epsilon\\xi` in the geometry cases.

        Returns
        -------
        (m,) ndarray
        """
        theta = as_finite_array("theta", theta, shape=(self.system.N,))
        return self._evaluation_matrix(points) @ theta

    def force_density(self, lam, points, eps=None):
        """Reference force density :math:`\\sum_j \\lambda_j\\phi_j(\\xi)` at ``points``.

        In physical units the density is this divided by the Jacobian
        :math:`\\prod_m \\epsilon_m` (geometry cases; pass ``eps``).

        Parameters
        ----------
        lam : (C,) array_like
        points : (m,) or (m, 2) array_like
        eps : (n_eps,) array_like, optional
            When given in a geometry case, the physical density is returned.

        Returns
        -------
        (m,) ndarray
        """
        lam = as_finite_array("lam", lam, shape=(self.centers.shape[0],))
        phi = self._force_shapes(points)
        dens = phi @ lam
        if eps is not None and self._positive:
            dens = dens / float(np.prod(self.check_eps(eps)))
        return dens

    def _force_shapes(self, points):
        if self.kind == "rectangle":
            p = as_finite_array("points", points, ndim=2)
            om = self.force_width
            d2 = ((p[:, None, :] - self.centers[None, :, :]) ** 2).sum(-1)
            return (om / np.pi) * np.exp(-om * d2)
        x = as_finite_array("points", points, ndim=1)
        a = self.force_width
        return np.maximum(0.0, 1.0 - np.abs(x[:, None] - self.centers[None, :]) / a)

    def _evaluation_matrix(self, points):
        if self.kind == "rectangle":
            p = as_finite_array("points", points, ndim=2)
            return self._basis.evaluate(p)
        x = as_finite_array("points", points, ndim=1)
        E = self._basis.evaluate(x)
        if self.kind == "boundary":
            E = np.column_stack([E, 1.0 - x])
        return E


def _check_sizes(eps):
    if np.any(eps <= 0):
        raise ValueError(
            f"domain sizes `eps` must be positive, got {np.asarray(eps).tolist()}; "
            "a length is the unknown here, so pass values > 0"
        )


# --------------------------------------------------------------------------------------
# helpers shared by the builders
# --------------------------------------------------------------------------------------
def uniform_sensors(count, dim=1):
    """Evenly spaced interior reference positions :math:`k/(C+1)`, ``k = 1..C``.

    Parameters
    ----------
    count : int
        Sensors per direction.
    dim : {1, 2}
        ``2`` returns the ``count x count`` grid, shape ``(count**2, 2)``.

    Returns
    -------
    (count,) or (count**2, 2) ndarray
    """
    count = check_int("count", count, minimum=1)
    x = np.arange(1, count + 1) / (count + 1)
    if dim == 1:
        return x
    if dim == 2:
        X, Y = np.meshgrid(x, x, indexing="ij")
        return np.column_stack([X.ravel(), Y.ravel()])
    raise ValueError(f"`dim` must be 1 or 2, got {dim!r}")


def gaussian_source(center, width, amplitude):
    """A localized heat source :math:`q\\,e^{-\\|x - x_0\\|^2 / (2\\rho^2)}` and its gradient.

    Used to make data from a model outside the parameterized family (an unmodelled
    source, or with :math:`q < 0` a sink).

    Parameters
    ----------
    center : float or (2,) array_like
        :math:`x_0` in physical coordinates.
    width : float
        :math:`\\rho > 0`.
    amplitude : float
        :math:`q` (any sign).

    Returns
    -------
    s : callable
        ``s(x)`` (1-D) or ``s(x, y)`` (2-D), vectorised.
    grad_s : callable
        ``grad_s(x) -> ds/dx`` (1-D) or ``grad_s(x, y) -> (ds/dx, ds/dy)`` (2-D).
    """
    c = as_finite_array("center", np.atleast_1d(center), ndim=1)
    rho = check_positive("width", width)
    q = float(as_finite_array("amplitude", amplitude, ndim=0))
    if c.size == 1:
        x0 = float(c[0])

        def s(x):
            return q * np.exp(-((np.asarray(x) - x0) ** 2) / (2 * rho**2))

        def ds(x):
            return -(np.asarray(x) - x0) / rho**2 * s(x)

        return s, ds
    if c.size == 2:
        x0, y0 = (float(v) for v in c)

        def s2(x, y):
            return q * np.exp(
                -((np.asarray(x) - x0) ** 2 + (np.asarray(y) - y0) ** 2) / (2 * rho**2)
            )

        def ds2(x, y):
            v = s2(x, y)
            return -(np.asarray(x) - x0) / rho**2 * v, -(np.asarray(y) - y0) / rho**2 * v

        return s2, ds2
    raise ValueError(f"`center` must be a number or a pair, got shape {c.shape}")


def _as_source(s, ds, dim):
    """Normalize a source given as a number or a callable (with optional gradient)."""
    if isinstance(s, numbers.Real) and not isinstance(s, bool):
        c = float(s)
        if not np.isfinite(c):
            raise ValueError(f"`s` must be finite, got {c}")
        if dim == 1:
            return (lambda x: np.full(np.shape(x), c)), (lambda x: np.zeros(np.shape(x)))
        return (lambda x, y: np.full(np.broadcast(x, y).shape, c)), (
            lambda x, y: (np.zeros(np.broadcast(x, y).shape), np.zeros(np.broadcast(x, y).shape))
        )
    if not callable(s):
        raise TypeError(f"`s` must be a number or a callable, got {type(s).__name__}")
    if ds is not None and not callable(ds):
        raise TypeError(f"`grad_s` must be callable or None, got {type(ds).__name__}")
    return s, ds


def _finite(name, values):
    values = np.asarray(values, dtype=float)
    if not np.all(np.isfinite(values)):
        raise ValueError(f"`{name}` returned NaN or inf; check the source function")
    return values


def _check_sensor_count(count, n_eps, n_state, what):
    count = check_int("sensors", count, minimum=1)
    if count < n_eps:
        raise ValueError(
            f"`sensors` must give at least {n_eps} measurements to identify {n_eps} "
            f"parameter(s), got {count}"
        )
    if count > n_state:
        raise ValueError(
            f"`sensors` ({count}) exceeds the {what} ({n_state}); the ECFM constraint "
            "system would be singular. Use fewer sensors or a larger `n_basis`"
        )
    return count


# --------------------------------------------------------------------------------------
# boundary case
# --------------------------------------------------------------------------------------
def boundary_problem(n_basis=20, sensors=5, s=1.0, half_width=None):
    """Rod with unknown Dirichlet value :math:`w(0) = \\epsilon_1` and Neumann flux
    :math:`w'(1) = \\epsilon_2` (paper Section 4, parametric boundary conditions).

    Parameters
    ----------
    n_basis : int
        Number N of beam modes :math:`f_i = \\sin((2i-1)\\pi x/2)`.
    sensors : int or (C,) array_like
        Count of evenly spaced sensors :math:`k/(C+1)`, or their positions in (0, 1].
    s : float or callable
        Known source :math:`s(x)` (model and truth share it unless the truth adds more).
    half_width : float, optional
        Half-width of the hat constraint forces (default: the sensor spacing).

    Returns
    -------
    HeatProblem
        State :math:`(\\theta_1..\\theta_N, a)` of size ``N + 1``; the residual is

        .. math::

            \\begin{pmatrix} K & k_g \\\\ 0 & 1\\end{pmatrix}
            \\begin{pmatrix}\\theta \\\\ a\\end{pmatrix}
            - \\begin{pmatrix} F_s + \\epsilon_2 f(1) \\\\ \\epsilon_1\\end{pmatrix}
            - \\begin{pmatrix}\\Gamma \\\\ 0\\end{pmatrix}\\lambda,
            \\qquad (k_g)_j = \\int_0^1 g_1' f_j' = -f_j(1),

        with :math:`g = a\\,g_1`, :math:`g_1 = 1 - x`; with :math:`a = \\epsilon_1`
        substituted it is the paper's :math:`K\\theta = \\int s f + h f(1) - \\int g'f'`.
    """
    n = check_int("n_basis", n_basis, minimum=1)
    basis = BeamBasis(n)
    x_c = _sensor_positions(sensors, n_eps=2, n_state=n)
    s_fn, _ = _as_source(s, None, dim=1)
    a = _spacing(x_c) if half_width is None else check_positive("half_width", half_width)

    K = stiffness(basis)
    f1 = basis.evaluate(np.array([1.0]))[0]  # f_j(1) = +-1
    # int_0^1 g1' f_j' with g1 = 1 - x  ->  -(f_j(1) - f_j(0)) = -f_j(1)
    kg = -f1
    K_aug = np.zeros((n + 1, n + 1))
    K_aug[:n, :n] = K
    K_aug[:n, n] = kg
    K_aug[n, n] = 1.0
    F_s = np.append(_finite("s", load(basis, s_fn)), 0.0)
    # dF/deps: the Neumann flux enters through h f(1); the lift row carries eps_1
    B = np.zeros((n + 1, 2))
    B[:n, 1] = f1
    B[n, 0] = 1.0
    Gamma = np.vstack([hat_forces(basis, x_c, a), np.zeros((1, x_c.size))])
    system = GalerkinSystem(
        [
            LinearTerm(K_aug, name="stiffness + lift"),
            LoadTerm.constant(F_s, name="source"),
            LoadTerm.linear(B, name="boundary data"),
        ],
        n_eps=2,
        Gamma=Gamma,
        name="heat-boundary",
    )
    M_obs = np.column_stack([sensor_matrix(basis, x_c), 1.0 - x_c])
    return HeatProblem(
        system=system,
        M_obs=M_obs,
        sensors=x_c,
        kind="boundary",
        eps_names=("w(0)", "w'(1)"),
        bounds=[(None, None), (None, None)],
        centers=x_c,
        force_width=a,
        _basis=basis,
        _positive=False,
    )


# --------------------------------------------------------------------------------------
# geometry: interval [0, L]
# --------------------------------------------------------------------------------------
def interval_problem(n_basis=20, sensors=5, s=None, grad_s=None, half_width=None):
    """Rod :math:`[0, L]` of unknown length :math:`L = \\epsilon_1`, :math:`w = 0` at both
    ends (paper Section 4, parametric domain geometry).

    Parameters
    ----------
    n_basis : int
        Number N of sine modes :math:`\\sin(i\\pi\\xi)` on the reference interval.
    sensors : int or (C,) array_like
        Count of sensors at reference fractions :math:`k/(C+1)`, or the fractions.
    s, grad_s : float or callable, callable
        Source :math:`s(x)` in *physical* coordinates and its derivative (needed for
        :math:`\\partial F/\\partial L`). Default :math:`s = 1 + x`.
    half_width : float, optional
        Reference half-width of the hat constraint forces (default: sensor spacing).

    Returns
    -------
    HeatProblem
        With :math:`K(L) = K_{ref}/L` and
        :math:`F(L) = L\\int_0^1 s(L\\xi) f\\,d\\xi`,
        :math:`\\partial F/\\partial L = \\int_0^1 [s(L\\xi) + L\\xi s'(L\\xi)] f\\,d\\xi`.
    """
    if s is None:
        s, grad_s = (lambda x: 1.0 + np.asarray(x)), (lambda x: np.ones(np.shape(x)))
    s_fn, ds_fn = _as_source(s, grad_s, dim=1)
    n = check_int("n_basis", n_basis, minimum=1)
    basis = SineBasis(n)
    x_c = _sensor_positions(sensors, n_eps=1, n_state=n)
    a = _spacing(x_c) if half_width is None else check_positive("half_width", half_width)
    K_ref = stiffness(basis)
    xq, wq = composite_gauss((), 2 * n + 40)
    fq = basis.evaluate(xq)  # (q, N)

    def F(eps, t=None):
        L = _length(eps)
        return L * (fq.T @ (wq * _finite("s", s_fn(L * xq))))

    def dF(eps, t=None):
        if ds_fn is None:
            raise ValueError("dF/dL needs the source derivative: pass `grad_s`")
        L = _length(eps)
        integrand = _finite("s", s_fn(L * xq)) + L * xq * _finite("grad_s", ds_fn(L * xq))
        return (fq.T @ (wq * integrand))[:, None]

    coef = Coefficient(
        lambda eps: 1.0 / _length(eps), lambda eps: np.array([-1.0 / _length(eps) ** 2])
    )
    system = GalerkinSystem(
        [LinearTerm(K_ref, coef, name="stiffness"), LoadTerm(F, dF, name="source")],
        n_eps=1,
        Gamma=hat_forces(basis, x_c, a),
        name="heat-interval",
    )
    return HeatProblem(
        system=system,
        M_obs=sensor_matrix(basis, x_c),
        sensors=x_c,
        kind="interval",
        eps_names=("L",),
        bounds=[(1e-3, None)],
        centers=x_c,
        force_width=a,
        _basis=basis,
        _positive=True,
    )


def _length(eps):
    L = float(eps[0])
    if not L > 0:
        raise ValueError(f"the domain length eps[0] must be positive, got {L}")
    return L


# --------------------------------------------------------------------------------------
# geometry: rectangle [0, a] x [0, b]
# --------------------------------------------------------------------------------------
def rectangle_problem(n_basis=12, sensors=4, s=None, grad_s=None, omega=None):
    """Plate :math:`[0, a]\\times[0, b]` of unknown size :math:`(a, b) = (\\epsilon_1,
    \\epsilon_2)`, :math:`w = 0` on the boundary (paper Section 4).

    Parameters
    ----------
    n_basis : int
        Sine modes per direction (state size :math:`N = n^2`).
    sensors : int or (C, 2) array_like
        Sensors per direction of a uniform grid at reference fractions
        :math:`k/(c+1)` (``C = c**2``), or the reference positions.
    s, grad_s : float or callable, callable
        Source :math:`s(x, y)` in physical coordinates and its gradient
        ``grad_s(x, y) -> (s_x, s_y)``. Default :math:`s = 1 + x`.
    omega : float, optional
        RBF width :math:`\\omega` of the constraint forces in reference coordinates
        (default: standard deviation half the sensor spacing,
        :math:`\\omega = 2/h^2`).

    Returns
    -------
    HeatProblem
        With :math:`K(\\epsilon) = (b/a) K_x\\otimes M_y + (a/b) M_x\\otimes K_y` and
        :math:`F(\\epsilon) = ab\\int\\!\\!\\int s(a\\xi, b\\eta) f` (module notes).
    """
    if s is None:
        s = lambda x, y: 1.0 + np.asarray(x) + 0.0 * np.asarray(y)
        grad_s = lambda x, y: (
            np.ones(np.broadcast(x, y).shape),
            np.zeros(np.broadcast(x, y).shape),
        )
    s_fn, ds_fn = _as_source(s, grad_s, dim=2)
    n = check_int("n_basis", n_basis, minimum=1)
    b1 = SineBasis(n)
    basis = TensorBasis2D(b1, b1)
    if isinstance(sensors, numbers.Integral) and not isinstance(sensors, bool):
        c = check_int("sensors", sensors, minimum=1)
        _check_sensor_count(c * c, 2, basis.size, "state size N = n_basis**2")
        p_c = uniform_sensors(c, dim=2)
        spacing = 1.0 / (c + 1)
    else:
        p_c = as_finite_array("sensors", sensors, ndim=2)
        if p_c.shape[1] != 2 or np.any((p_c <= 0) | (p_c >= 1)):
            raise ValueError("`sensors` positions must have shape (C, 2) inside (0, 1)^2")
        _check_sensor_count(p_c.shape[0], 2, basis.size, "state size N = n_basis**2")
        spacing = _spacing_2d(p_c)
    om = 2.0 / spacing**2 if omega is None else check_positive("omega", omega)

    Kx, Mx = stiffness(b1), mass(b1)
    KxMy, MxKy = np.kron(Kx, Mx), np.kron(Mx, Kx)
    xq, wq = composite_gauss((), 2 * n + 40)
    gq = b1.evaluate(xq)  # (q, n), same in x and y
    XI, ETA = np.meshgrid(xq, xq, indexing="ij")
    W = np.outer(wq, wq)

    def project(values):
        return (gq.T @ (W * values) @ gq).ravel()

    def F(eps, t=None):
        a, b = _sizes(eps)
        return a * b * project(_finite("s", s_fn(a * XI, b * ETA)))

    def dF(eps, t=None):
        if ds_fn is None:
            raise ValueError("dF/deps needs the source gradient: pass `grad_s`")
        a, b = _sizes(eps)
        sv = _finite("s", s_fn(a * XI, b * ETA))
        sx, sy = (_finite("grad_s", g) for g in ds_fn(a * XI, b * ETA))
        dFa = b * project(sv) + a * b * project(sx * XI)
        dFb = a * project(sv) + a * b * project(sy * ETA)
        return np.column_stack([dFa, dFb])

    c_x = Coefficient(
        lambda eps: _sizes(eps)[1] / _sizes(eps)[0],
        lambda eps: np.array([-eps[1] / eps[0] ** 2, 1.0 / eps[0]]),
    )
    c_y = Coefficient(
        lambda eps: _sizes(eps)[0] / _sizes(eps)[1],
        lambda eps: np.array([1.0 / eps[1], -eps[0] / eps[1] ** 2]),
    )
    system = GalerkinSystem(
        [
            LinearTerm(KxMy, c_x, name="b/a Kx(x)My"),
            LinearTerm(MxKy, c_y, name="a/b Mx(x)Ky"),
            LoadTerm(F, dF, name="source"),
        ],
        n_eps=2,
        Gamma=rbf_forces(basis, p_c, om),
        name="heat-rectangle",
    )
    return HeatProblem(
        system=system,
        M_obs=sensor_matrix(basis, p_c),
        sensors=p_c,
        kind="rectangle",
        eps_names=("a", "b"),
        bounds=[(1e-3, None), (1e-3, None)],
        centers=p_c,
        force_width=om,
        _basis=basis,
        _positive=True,
    )


def _sizes(eps):
    a, b = float(eps[0]), float(eps[1])
    if not (a > 0 and b > 0):
        raise ValueError(f"the domain sizes eps = ({a}, {b}) must be positive")
    return a, b


# --------------------------------------------------------------------------------------
# sensors
# --------------------------------------------------------------------------------------
def _sensor_positions(sensors, n_eps, n_state):
    if isinstance(sensors, numbers.Integral) and not isinstance(sensors, bool):
        count = _check_sensor_count(sensors, n_eps, n_state, "number of basis functions")
        return uniform_sensors(count)
    x = as_finite_array("sensors", sensors, ndim=1)
    if np.any((x <= 0) | (x > 1)):
        raise ValueError("`sensors` positions must lie in (0, 1]")
    if np.unique(x).size != x.size:
        raise ValueError("`sensors` positions must be distinct")
    _check_sensor_count(x.size, n_eps, n_state, "number of basis functions")
    return np.sort(x)


def _spacing(x):
    """Smallest gap between sensors and to x = 0 (default hat half-width)."""
    return float(np.min(np.diff(np.concatenate([[0.0], np.sort(x)]))))


def _spacing_2d(p):
    if p.shape[0] < 2:
        return float(min(p.min(), 1 - p.max()))
    d = np.sqrt(((p[:, None, :] - p[None, :, :]) ** 2).sum(-1))
    d[np.diag_indices_from(d)] = np.inf
    return float(d.min())


# the closed forms of the continuous BVPs live in heat_exact (re-exported here)
from .heat_exact import boundary_closed_form, interval_closed_form  # noqa: E402,F401
