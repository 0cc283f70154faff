"""Steady Fisher-KPP on the unit square with a misspecified source (paper Section 3.2).

The true system is Eq. (kpp),

.. math::

    \\mu\\nabla^2 u + r u (1 - u) + s = 0 \\ \\text{in}\\ \\Omega = [0, 1]^2, \\qquad
    u = 0 \\ \\text{on}\\ \\partial\\Omega,

with :math:`\\mu = 1/2`, :math:`r = 1` and the discontinuous source :math:`s = 100` on
:math:`[0.25, 0.75]^2` (0 elsewhere). The parameterized model, Eq. (kpp_param), replaces
:math:`s` by :math:`b(x; \\epsilon) = \\sum_\\alpha \\epsilon_\\alpha f_\\alpha(x)` on a coarse
sine basis (4 x 4), so no :math:`\\epsilon` reproduces :math:`s`. With the tensor sine
basis :math:`f_{(a,b)}(x, y) = \\sin(a\\pi x)\\sin(b\\pi y)` (10 x 10) the Galerkin form
(unnumbered equation after Eq. kpp_param, with the ECFM force of the equation before
Eq. ecfm_noise) is

.. math::

    \\tilde R(\\lambda, \\theta; \\epsilon) = \\mu K\\theta - r M\\theta
        + r A:\\theta\\otimes\\theta - F\\epsilon - \\Gamma\\lambda = 0,

    K = K_x\\otimes M_y + M_x\\otimes K_y,\\quad M = M_x\\otimes M_y,\\quad
    A_{(a,b)(c,d)(e,f)} = a^x_{ace}\\,a^y_{bdf},

    F_{i\\alpha} = \\int_\\Omega f_i f_\\alpha,\\quad
    \\Gamma_{ij} = \\int_\\Omega f_i\\,\\frac{\\omega}{\\pi}e^{-\\omega\\|x - x_j\\|^2},

where :math:`a^x_{ace} = \\int_0^1 g_a g_c g_e` are the 1-D triple products. The paper
prints :math:`(K - M)\\theta`; the weak form it writes just above has :math:`\\tfrac12 K`,
which we use (:math:`\\mu = 1/2`). The cubic tensor :math:`A` is never formed: the
:class:`KroneckerTripleForm` applies it through its 1-D factors, so N = 40 x 40 needs a
few tens of MB (the dense tensor would need 33 GB).

This module only builds systems and data from the paper's equations (the data generator
uses the engine's Newton continuation, not an optimizer) and evaluates fields and errors
on fine quadrature grids; the inverse solvers live in :mod:`ecfm_uq.inverse.formulations.all_at_once`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validation import as_finite_array, check_int, check_positive
from ..spectral import (
    SineBasis,
    TensorBasis2D,
    composite_gauss,
    gram,
    gram_vector,
    mass,
    rbf_forces,
    sensor_matrix,
    stiffness,
    triple,
)
from ..system import (
    Coefficient,
    GalerkinSystem,
    LinearTerm,
    LoadTerm,
    QuadraticTerm,
    solve_continuation,
)

#: Paper settings of Section 3.2.
MU = 0.5
R_RATE = 1.0
SOURCE_AMPLITUDE = 100.0
SOURCE_BOX = (0.25, 0.75)
SENSOR_SPACING = 1.0 / 16.0
#: Default RBF width: the Gaussian's standard deviation equals the sensor spacing h,
#: omega = 1 / (2 h^2) = 128 (the paper does not state omega).
DEFAULT_OMEGA = 1.0 / (2.0 * SENSOR_SPACING**2)


# --------------------------------------------------------------------------------------
# Kronecker-factored quadratic form
# --------------------------------------------------------------------------------------
class KroneckerTripleForm:
    """Quadratic form :math:`q(x, y)_i = A_{ijk} x_j y_k` with :math:`A = a^x \\otimes a^y`.

    For a tensor basis with row-major flat index ``i = a * Ny + b``,
    :math:`A_{(a,b)(c,d)(e,f)} = a^x_{ace}\\,a^y_{bdf}`. Implements the protocol of
    :class:`ecfm_uq.system.DenseQuadraticForm` (``size``, ``apply``, ``matrix``) without
    forming the :math:`N^3` tensor.

    Parameters
    ----------
    ax : (Nx, Nx, Nx) array_like
        1-D factor in x, e.g. :math:`\\int_0^1 g_a g_c g_e\\,dx`.
    ay : (Ny, Ny, Ny) array_like
        1-D factor in y.

    Notes
    -----
    ``apply`` costs :math:`O(m(N_x N_y^3 + N_x^2 N_y^2 + N_x^3 N_y))` for ``m`` columns and
    ``matrix`` :math:`O(N_x N_y^3 + N_x^3 N_y^2)`, against :math:`O(N^3)` for a dense form.
    """

    def __init__(self, ax, ay):
        self.ax = as_finite_array("ax", ax, ndim=3)
        self.ay = as_finite_array("ay", ay, ndim=3)
        for name, a in (("ax", self.ax), ("ay", self.ay)):
            n = a.shape[0]
            if a.shape != (n, n, n):
                raise ValueError(f"`{name}` must have shape (n, n, n), got {a.shape}")
        self.nx, self.ny = self.ax.shape[0], self.ay.shape[0]
        # A_ikj = ax[a,e,c] ay[b,f,d]: a second Kronecker term unless both factors are
        # symmetric in their last two indices (true for triple products of one basis).
        self._symmetric = np.allclose(self.ax, self.ax.transpose(0, 2, 1), rtol=0, atol=1e-14) and (
            np.allclose(self.ay, self.ay.transpose(0, 2, 1), rtol=0, atol=1e-14)
        )

    @classmethod
    def from_basis(cls, basis):
        """Triple-product form :math:`A_{ijk} = \\int_\\Omega f_i f_j f_k` of a tensor basis.

        Parameters
        ----------
        basis : TensorBasis2D
        """
        if not isinstance(basis, TensorBasis2D):
            raise TypeError(f"`basis` must be a TensorBasis2D, got {type(basis).__name__}")
        ax = triple(basis.bx)
        return cls(ax, ax if basis.by is basis.bx else triple(basis.by))

    @property
    def size(self):
        """N = Nx * Ny."""
        return self.nx * self.ny

    def apply(self, X, Y):
        """Column-wise :math:`A_{ijk} X_{jm} Y_{km}`.

        Parameters
        ----------
        X, Y : (N, m) ndarray

        Returns
        -------
        (N, m) ndarray
        """
        X = np.asarray(X, dtype=float)
        Y = np.asarray(Y, dtype=float)
        m = X.shape[1]
        X3 = X.reshape(self.nx, self.ny, m)
        Y3 = Y.reshape(self.nx, self.ny, m)
        # U[e,b,d,m] = ay[b,d,f] Y[e,f,m]; Z[c,e,b,m] = X[c,d,m] U[e,b,d,m];
        # q[a,b,m] = ax[a,c,e] Z[c,e,b,m]
        U = np.einsum("bdf,efm->ebdm", self.ay, Y3, optimize=True)
        Z = np.einsum("cdm,ebdm->cebm", X3, U, optimize=True)
        q = self.ax.reshape(self.nx, -1) @ Z.reshape(self.nx * self.nx, -1)
        return q.reshape(self.size, m)

    def _half_matrix(self, ax, ay, x2):
        # S[a,b,c,d] = sum_{e,f} ax[a,c,e] ay[b,d,f] x[e,f]
        B = np.einsum("bdf,ef->ebd", ay, x2, optimize=True)
        S = (ax.reshape(self.nx * self.nx, self.nx) @ B.reshape(self.nx, -1)).reshape(
            self.nx, self.nx, self.ny, self.ny
        )
        return S.transpose(0, 2, 1, 3).reshape(self.size, self.size)

    def matrix(self, x):
        """:math:`S(x)_{ij} = (A_{ijk} + A_{ikj}) x_k`, the Jacobian of :math:`A:x\\otimes x`.

        Parameters
        ----------
        x : (N,) ndarray

        Returns
        -------
        (N, N) ndarray
        """
        x2 = np.asarray(x, dtype=float).reshape(self.nx, self.ny)
        S = self._half_matrix(self.ax, self.ay, x2)
        if self._symmetric:
            return 2.0 * S
        return S + self._half_matrix(self.ax.transpose(0, 2, 1), self.ay.transpose(0, 2, 1), x2)

    def dense(self):
        """The dense (N, N, N) tensor (for tests at small N only)."""
        A = np.einsum("ace,bdf->abcdef", self.ax, self.ay)
        return A.reshape(self.size, self.size, self.size)


# --------------------------------------------------------------------------------------
# the problem
# --------------------------------------------------------------------------------------
def sensor_grid(n=15):
    """The paper's uniform interior sensor grid :math:`x = k/(n+1)`, :math:`k = 1..n`.

    Parameters
    ----------
    n : int
        Sensors per direction (15 gives the paper's C = 225 at spacing 1/16).

    Returns
    -------
    (n * n, 2) ndarray
        Row-major: sensor ``i * n + j`` sits at ``(x_i, y_j)``.
    """
    n = check_int("n", n, minimum=1)
    t = np.arange(1, n + 1) / (n + 1)
    X, Y = np.meshgrid(t, t, indexing="ij")
    return np.column_stack([X.ravel(), Y.ravel()])


def _check_sensors(sensors):
    p = as_finite_array("sensors", sensors, ndim=2)
    if p.shape[1] != 2 or p.shape[0] < 1:
        raise ValueError(f"`sensors` must have shape (C, 2) with C >= 1, got {p.shape}")
    if np.any((p <= 0.0) | (p >= 1.0)):
        raise ValueError(
            "`sensors` must lie strictly inside the unit square (0, 1)^2: the state vanishes "
            "on the boundary, so a sensor there measures nothing"
        )
    return p


@dataclass(frozen=True)
class KPPProblem:
    """The discretized Fisher-KPP model of Section 3.2 and its measurement set-up.

    Attributes
    ----------
    basis : TensorBasis2D
        State basis (N = Nx * Ny functions).
    source_basis : TensorBasis2D
        Source basis for :math:`b(x;\\epsilon)` (M functions, ``n_eps = M``).
    system : GalerkinSystem
        :math:`\\tilde R(\\lambda, \\theta; \\epsilon)` with ``Gamma`` set (ECFM forces); with
        :math:`\\lambda = 0` it is the standard model :math:`R(\\theta;\\epsilon)`.
    sensors : (C, 2) ndarray
    M_obs : (C, N) ndarray
        :math:`\\mathcal M_{ij} = f_j(x_i)`.
    Gamma : (N, C) ndarray
        RBF constraint-force vectors.
    F : (N, M) ndarray
        :math:`F_{i\\alpha} = \\int f_i f_\\alpha`.
    L : (N, N) ndarray
        Linear operator :math:`\\mu K - r M`.
    A : KroneckerTripleForm
        :math:`r A` is the quadratic term.
    omega, mu, r : float
    """

    basis: TensorBasis2D
    source_basis: TensorBasis2D
    system: GalerkinSystem
    sensors: np.ndarray
    M_obs: np.ndarray
    Gamma: np.ndarray
    F: np.ndarray
    L: np.ndarray
    A: KroneckerTripleForm
    omega: float
    mu: float
    r: float

    @property
    def n_eps(self):
        """Number of source parameters M."""
        return self.source_basis.size


def build_kpp(n_state=10, n_source=4, sensors=None, omega=DEFAULT_OMEGA, mu=MU, r=R_RATE):
    """Build the Fisher-KPP model of Eq. (kpp_param) with RBF constraint forces.

    Parameters
    ----------
    n_state : int
        Sines per direction in the state basis (paper: 10, N = 100).
    n_source : int
        Sines per direction in the source basis (paper: 4, M = 16).
    sensors : (C, 2) array_like, optional
        Sensor positions strictly inside the unit square (default :func:`sensor_grid`,
        C = 225).
    omega : float
        RBF width :math:`\\omega` of :math:`\\Gamma(x) = (\\omega/\\pi) e^{-\\omega\\|x\\|^2}`
        (default 128: standard deviation equal to the sensor spacing 1/16).
    mu, r : float
        Diffusion and reaction rates (paper: 1/2 and 1).

    Returns
    -------
    KPPProblem
    """
    nx = check_int("n_state", n_state, minimum=1)
    ns = check_int("n_source", n_source, minimum=1)
    omega = check_positive("omega", omega)
    mu = check_positive("mu", mu)
    r = check_positive("r", r)
    sensors = sensor_grid() if sensors is None else _check_sensors(sensors)

    bx = SineBasis(nx)
    basis = TensorBasis2D(bx, bx)
    sx = SineBasis(ns)
    source_basis = TensorBasis2D(sx, sx)

    Mx, Kx = mass(bx), stiffness(bx)
    # mu K - r M with K = Kx (x) Mx + Mx (x) Kx; dense (N, N) only because LinearTerm
    # needs it (20 MB at N = 1600)
    L = mu * (np.kron(Kx, Mx) + np.kron(Mx, Kx)) - r * np.kron(Mx, Mx)
    A = KroneckerTripleForm.from_basis(basis)
    Fx = gram(bx, sx)
    F = np.kron(Fx, Fx)
    Gamma = rbf_forces(basis, sensors, omega)
    M_obs = sensor_matrix(basis, sensors)

    system = GalerkinSystem(
        [
            LinearTerm(L, name="mu K - r M"),
            QuadraticTerm(A, coef=r, name="r A"),
            LoadTerm.linear(F),
        ],
        n_eps=source_basis.size,
        Gamma=Gamma,
        name="fisher-kpp",
    )
    return KPPProblem(basis, source_basis, system, sensors, M_obs, Gamma, F, L, A, omega, mu, r)


# --------------------------------------------------------------------------------------
# the true source, the true state and the data
# --------------------------------------------------------------------------------------
def true_source(points, amplitude=SOURCE_AMPLITUDE, box=SOURCE_BOX):
    """The discontinuous true source :math:`s(x)` of Section 3.2.

    Parameters
    ----------
    points : (m, 2) array_like
    amplitude : float
    box : (float, float)
        :math:`s = ` ``amplitude`` on ``box`` x ``box``.

    Returns
    -------
    (m,) ndarray
    """
    p = as_finite_array("points", points, ndim=2)
    lo, hi = box
    inside = np.all((p >= lo) & (p <= hi), axis=1)
    return np.where(inside, float(amplitude), 0.0)


def true_load(basis, amplitude=SOURCE_AMPLITUDE, box=SOURCE_BOX):
    """Galerkin load :math:`\\int_\\Omega s f_i` of the true source, exact to round-off.

    The integral factorizes, :math:`s_0 \\int_{lo}^{hi} g_a\\,dx \\int_{lo}^{hi} h_b\\,dy`;
    the box edges are quadrature breakpoints.

    Returns
    -------
    (N,) ndarray
    """
    lo, hi = box
    ind = lambda x: ((x >= lo) & (x <= hi)).astype(float)
    gx = gram_vector(basis.bx, ind, breakpoints=(lo, hi))
    gy = gram_vector(basis.by, ind, breakpoints=(lo, hi))
    return float(amplitude) * np.kron(gx, gy)


def true_system(problem, amplitude=SOURCE_AMPLITUDE, box=SOURCE_BOX):
    """The true model, Eq. (kpp), on the state basis: :math:`\\mu K\\theta - r M\\theta + r
    A:\\theta\\otimes\\theta - t\\,F_s = 0` with the load scale :math:`t` as its single
    parameter (t = 1 is the true problem; smaller t serve load continuation).

    Returns
    -------
    GalerkinSystem
        ``n_eps = 1``, no constraint forces.
    """
    Fs = true_load(problem.basis, amplitude, box)
    return GalerkinSystem(
        [
            LinearTerm(problem.L, name="mu K - r M"),
            QuadraticTerm(problem.A, coef=problem.r, name="r A"),
            LoadTerm.scaled(Fs, Coefficient.parameter(0), name="true load"),
        ],
        n_eps=1,
        name="fisher-kpp-true",
    )


@dataclass(frozen=True)
class KPPData:
    """Synthetic measurements of Section 3.2.

    Attributes
    ----------
    theta_true : (N,) ndarray
        Noiseless true state on the state basis (the reference u of the error).
    v_clean : (C,) ndarray
        :math:`\\mathcal M\\theta_{true}`.
    noise : (C,) ndarray
        :math:`N(0, \\sigma^2)` draws.
    v : (C,) ndarray
        Measured data ``v_clean + noise``.
    sigma : float
    seed : int
    continuation_steps : int
        Load steps the Newton solve needed (1: converged from zero directly).
    newton_iterations : int
        Newton iterations summed over the load steps.
    """

    theta_true: np.ndarray
    v_clean: np.ndarray
    noise: np.ndarray
    v: np.ndarray
    sigma: float
    seed: int
    continuation_steps: int
    newton_iterations: int


def solve_true_state(
    problem, amplitude=SOURCE_AMPLITUDE, box=SOURCE_BOX, max_halvings=6, tol=1e-10
):
    """Solve the true problem by Newton, with load continuation if needed.

    Delegates to :func:`ecfm_uq.system.solve_continuation` along the load scale 0 -> 1:
    Newton from zero at the full load first, then ``2, 4, 8, ...`` load steps.

    Returns
    -------
    theta : (N,) ndarray
    steps : int
        Number of load steps used.
    nit : int
        Total Newton iterations.

    Raises
    ------
    ConvergenceError
        If even ``2**max_halvings`` load steps fail.
    """
    sysm = true_system(problem, amplitude, box)
    # the true system's one parameter scales the load; zero load has the zero solution
    sol, steps = solve_continuation(
        sysm, [0.0], [1.0], max_halvings=max_halvings, tol=tol, strict=True
    )
    return sol.Theta[:, 0], steps, sol.nit


def make_data(problem, sigma=0.05, seed=0, amplitude=SOURCE_AMPLITUDE, box=SOURCE_BOX):
    """Noisy measurements of the true state (Section 3.2): :math:`v = \\mathcal M\\theta_{true}
    + \\eta`, :math:`\\eta \\sim N(0, \\sigma^2 I)` from ``numpy.random.default_rng(seed)``.

    Parameters
    ----------
    problem : KPPProblem
    sigma : float
        Noise standard deviation (paper: 0.05).
    seed : int
    amplitude : float
        True source value on the box (paper: 100).
    box : (float, float)

    Returns
    -------
    KPPData
    """
    sigma = check_positive("sigma", sigma)
    seed = check_int("seed", seed, minimum=0)
    theta, steps, nit = solve_true_state(problem, amplitude, box)
    v_clean = problem.M_obs @ theta
    noise = sigma * np.random.default_rng(seed).standard_normal(v_clean.size)
    return KPPData(theta, v_clean, noise, v_clean + noise, sigma, seed, steps, nit)


# --------------------------------------------------------------------------------------
# fields and errors on a fine grid
# --------------------------------------------------------------------------------------
def fine_grid(panels=32, n_per_panel=8):
    """1-D composite Gauss rule on [0, 1] with panel edges at ``k / panels``.

    With ``panels`` a multiple of 4 the source box edges 0.25, 0.75 are panel edges, so
    the discontinuous source is integrated without a straddled jump.

    Returns
    -------
    x : (n,) ndarray
    w : (n,) ndarray
    """
    panels = check_int("panels", panels, minimum=1)
    return composite_gauss(np.arange(1, panels) / panels, n_per_panel)


def relative_l1_error(problem, theta_ref, theta, grid=None):
    """:math:`\\mathcal E = \\int|u - w| / \\int|u|` on a tensor fine grid (Section 3.2).

    Parameters
    ----------
    problem : KPPProblem
    theta_ref : (N,) array_like
        Coefficients of the reference field u.
    theta : (N,) array_like
        Coefficients of the approximation w.
    grid : (x, w), optional
        1-D rule (default :func:`fine_grid`).

    Returns
    -------
    float
    """
    theta_ref = as_finite_array("theta_ref", theta_ref, shape=(problem.basis.size,))
    theta = as_finite_array("theta", theta, shape=(problem.basis.size,))
    x, w = fine_grid() if grid is None else grid
    W = np.outer(w, w)
    u = problem.basis.evaluate_grid(theta_ref, x, x)
    v = problem.basis.evaluate_grid(theta, x, x)
    den = float(np.sum(W * np.abs(u)))
    if den == 0.0:
        raise ValueError("`theta_ref` is the zero field; the relative error is undefined")
    return float(np.sum(W * np.abs(u - v))) / den


def force_field(problem, lam, x, y):
    """:math:`\\sum_j \\lambda_j \\Gamma(x - x_j)` on the grid ``x`` by ``y``.

    Returns
    -------
    (len(x), len(y)) ndarray
    """
    lam = as_finite_array("lam", lam, shape=(problem.sensors.shape[0],))
    om = problem.omega
    gx = np.sqrt(om / np.pi) * np.exp(-om * (x[:, None] - problem.sensors[None, :, 0]) ** 2)
    gy = np.sqrt(om / np.pi) * np.exp(-om * (y[:, None] - problem.sensors[None, :, 1]) ** 2)
    return (gx * lam[None, :]) @ gy.T


def source_field(problem, eps, x, y, lam=None):
    """Recovered source :math:`b(x;\\epsilon)`, plus the constraint forces if ``lam`` given.

    Returns
    -------
    (len(x), len(y)) ndarray
    """
    eps = as_finite_array("eps", eps, shape=(problem.n_eps,))
    b = problem.source_basis.evaluate_grid(eps, x, y)
    return b if lam is None else b + force_field(problem, lam, x, y)


def source_relative_error(problem, eps, lam=None, norm="l1", grid=None, **true_kw):
    """Relative error of the recovered source against the discontinuous true :math:`s`.

    :math:`\\|s - b - \\sum\\lambda_j\\Gamma_j\\| / \\|s\\|` in L1 (default) or L2 on a fine
    grid whose panel edges contain the box edges.

    Parameters
    ----------
    problem : KPPProblem
    eps : (M,) array_like
    lam : (C,) array_like, optional
        Constraint forces to add (``None``: b alone).
    norm : {"l1", "l2"}
    grid : (x, w), optional

    Returns
    -------
    float
    """
    if norm not in ("l1", "l2"):
        raise ValueError(f"unknown `norm` {norm!r}; choose 'l1' or 'l2'")
    x, w = fine_grid() if grid is None else grid
    W = np.outer(w, w)
    X, Y = np.meshgrid(x, x, indexing="ij")
    s = true_source(np.column_stack([X.ravel(), Y.ravel()]), **true_kw).reshape(X.shape)
    d = s - source_field(problem, eps, x, x, lam)
    if norm == "l1":
        return float(np.sum(W * np.abs(d)) / np.sum(W * np.abs(s)))
    return float(np.sqrt(np.sum(W * d**2) / np.sum(W * s**2)))


__all__ = [
    "DEFAULT_OMEGA",
    "KPPData",
    "KPPProblem",
    "KroneckerTripleForm",
    "build_kpp",
    "fine_grid",
    "force_field",
    "make_data",
    "relative_l1_error",
    "sensor_grid",
    "solve_true_state",
    "source_field",
    "source_relative_error",
    "true_load",
    "true_source",
    "true_system",
]
