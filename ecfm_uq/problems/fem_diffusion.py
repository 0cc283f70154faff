"""2-D stochastic diffusion on the unit square with P1 finite elements from scikit-fem.

.. math::

    -\\nabla\\cdot\\bigl(a(x,\\omega;\\epsilon)\\nabla u\\bigr) = f \\ \\text{in } (0,1)^2,
    \\qquad u = 0 \\text{ on the boundary},

    a(x,\\omega;\\epsilon) = 10^{\\epsilon_0} a_0 + \\epsilon_1\\,b(x)
        + \\sum_{k=1}^{d} \\sigma_k\\,\\phi_k(x)\\,(\\omega_k - \\tfrac12),

or, with ``patches=m``, a spatially varying mean conductivity
:math:`10^{\\epsilon_p} a_0` on each of :math:`m\\times m` square patches (then
:math:`\\epsilon_{m^2}` is the inclusion amplitude),

with smooth modes :math:`\\phi_k(x) = \\cos(\\pi m_k x_1)\\cos(\\pi n_k x_2)`, a Gaussian
inclusion :math:`b(x)` and :math:`\\omega\\sim U(0,1)^d`. The Galerkin projection in
space (scikit-fem assembles sparse :math:`K_0, K_b, K_k` and :math:`F` on the interior
nodes) and in the chaos (paper Eq. pce) gives

.. math::

    R = 10^{\\epsilon_0} a_0 K_0\\Theta + \\epsilon_1 K_b\\Theta
        + \\sum_k K_k\\Theta\\,\\mathbb E[(\\omega_k - \\tfrac12)\\Psi\\Psi^T]
        - F\\,\\mathbb E[\\Psi]^T - \\Gamma\\lambda\\,\\mathbb E[\\Psi]^T,

a sum of Kronecker products that the engine applies matrix-free. Point sensors give
:math:`\\mathcal M` from the P1 basis functions at the sensor points (a sparse (C, N)
matrix); the constraint forces are Gaussian bumps at the sensors, assembled as loads.

This module only builds systems (the stochastic one and, for collocation, the
deterministic one at a germ point); solving is the engine's job. It needs the ``fem``
extra: ``pip install "ecfm-uq[fem]"``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .._validation import as_finite_array, check_int, check_positive
from ..chaos import ChaosBasis, weighted_gram
from ..system import Coefficient, GalerkinSystem, LinearTerm, LoadTerm

__all__ = ["FemDiffusion", "build_fem_diffusion", "DEFAULT_MODES", "DEFAULT_SIGMAS"]

# (m_k, n_k) of phi_k(x) = cos(pi m_k x1) cos(pi n_k x2)
DEFAULT_MODES = ((1, 0), (0, 1), (1, 1), (2, 0))
# a varies by +-0.2 around a0 = 1 (sum sigma_k / 2): order 3 reaches 1e-6 in the variance
DEFAULT_SIGMAS = (0.16, 0.12, 0.08, 0.04)


def _skfem():
    try:
        import skfem
    except ImportError as e:
        raise ImportError(
            'the finite-element models need scikit-fem: pip install "ecfm-uq[fem]"'
        ) from e
    return skfem


@dataclass
class FemDiffusion:
    """The assembled model.

    Attributes
    ----------
    system : GalerkinSystem
        Stochastic system, ``n_eps = 2`` (:math:`\\epsilon_0` log-scale of the mean
        conductivity, :math:`\\epsilon_1` inclusion amplitude), state (N, P) on the
        interior nodes, with constraint forces at the sensors.
    chaos : ChaosBasis
    mesh, fem_basis
        scikit-fem mesh and P1 basis.
    interior : (N,) ndarray
        Mesh node indices of the unknowns.
    sensors : (C, 2) ndarray
    M_obs : (C, N) scipy.sparse.csr_matrix
        Sensor matrix: P1 basis functions at the sensor points.
    mean_terms : list of (csr_matrix, Coefficient, str)
        The deterministic part of the conductivity: ``(K, c(eps), name)`` for
        :math:`10^{\\epsilon_0}a_0 K_0` (or one per patch) and the inclusion
        :math:`\\epsilon_{-1} K_b`.
    K0, Kb : (N, N) csr_matrix
        :math:`\\int \\nabla u\\cdot\\nabla v` and :math:`\\int b\\,\\nabla u\\cdot\\nabla v`
        (``Kb`` is ``None`` without an inclusion).
    K_modes : list of (N, N) csr_matrix
        :math:`\\int \\sigma_k\\phi_k\\nabla u\\cdot\\nabla v`.
    F : (N,) ndarray
    Gamma : (N, C) ndarray
    a0 : float
    """

    system: GalerkinSystem
    chaos: ChaosBasis
    mesh: object
    fem_basis: object
    interior: np.ndarray
    sensors: np.ndarray
    M_obs: sp.csr_matrix
    mean_terms: list
    K0: sp.csr_matrix
    Kb: sp.csr_matrix | None
    K_modes: list
    F: np.ndarray
    Gamma: np.ndarray
    a0: float

    @property
    def n_nodes(self):
        """Mesh nodes (boundary included)."""
        return self.mesh.p.shape[1]

    def deterministic_system(self, omega):
        """The ``P = 1`` system at germ point ``omega`` (d,): one collocation sample.

        Its conductivity is the random field evaluated at ``omega``; same parameters,
        forces and sensors as :attr:`system`.
        """
        d = len(self.K_modes)
        omega = as_finite_array("omega", np.atleast_1d(omega), shape=(d,))
        if np.any((omega < 0) | (omega > 1)):
            raise ValueError(f"`omega` must lie in [0, 1]^{d}, got {omega}")
        K_omega = sum((w - 0.5) * K for w, K in zip(omega, self.K_modes, strict=True))
        terms = [LinearTerm(K, c, name=name) for K, c, name in self.mean_terms]
        terms += [
            LinearTerm(sp.csr_matrix(K_omega), name="random field at omega"),
            LoadTerm.constant(self.F),
        ]
        n_eps = self.system.n_eps
        return GalerkinSystem(terms, n_eps, Gamma=self.Gamma, name="fem-diffusion (sample)")

    def nodal(self, values):
        """Interior values (N,) -> values at every mesh node (zero on the boundary)."""
        out = np.zeros(self.n_nodes)
        out[self.interior] = values
        return out


def build_fem_diffusion(
    n_cells=32,
    order=3,
    *,
    modes=DEFAULT_MODES,
    sigmas=DEFAULT_SIGMAS,
    a0=1.0,
    sensors=None,
    force_width=None,
    inclusion=((0.3, 0.6), 0.1),
    patches=None,
):
    """Assemble the stochastic 2-D diffusion problem.

    Parameters
    ----------
    n_cells : int
        Cells per side of a uniform triangulation (``(n_cells + 1)^2`` nodes).
    order : int
        Total chaos order (``d = len(modes)`` germ variables, ``P = C(d + p, p)``).
    modes : sequence of (int, int)
        :math:`(m_k, n_k)` of the random-field modes.
    sigmas : sequence of float
        Their amplitudes; :math:`a > 0` needs :math:`10^{\\epsilon_0}a_0 >
        \\sum_k|\\sigma_k|/2` (checked at :math:`\\epsilon = 0`).
    a0 : float
        Mean conductivity at :math:`\\epsilon_0 = 0`.
    sensors : (C, 2) array_like, optional
        Sensor points inside the square; default a 3 x 3 grid at 1/4, 1/2, 3/4.
    force_width : float, optional
        Standard deviation of the Gaussian constraint forces (default: half the sensor
        spacing, 0.125 for the default grid).
    inclusion : ((float, float), float) or None
        Centre and standard deviation of :math:`b(x)`; ``None``: no inclusion term (and
        no parameter for it).
    patches : int, optional
        Calibrate a spatially varying mean conductivity: ``patches**2`` parameters, one
        log-conductivity per square patch, plus the inclusion amplitude last.

    Returns
    -------
    FemDiffusion
    """
    skfem = _skfem()
    from skfem.helpers import dot, grad

    n_cells = check_int("n_cells", n_cells, minimum=2)
    order = check_int("order", order, minimum=0)
    a0 = check_positive("a0", a0)
    modes = [tuple(int(c) for c in m) for m in modes]
    sigmas = as_finite_array("sigmas", sigmas, ndim=1)
    if len(modes) != sigmas.size or not modes:
        raise ValueError(
            f"`modes` and `sigmas` must have the same positive length, got {len(modes)} "
            f"and {sigmas.size}"
        )
    if np.sum(np.abs(sigmas)) / 2 >= a0:
        raise ValueError(
            f"the conductivity can reach zero: a0={a0} <= sum|sigmas|/2 = "
            f"{np.sum(np.abs(sigmas)) / 2}; lower `sigmas` or raise `a0`"
        )
    if sensors is None:
        g = np.array([0.25, 0.5, 0.75])
        sensors = np.array([(x, y) for y in g for x in g])
    sensors = as_finite_array("sensors", sensors, shape=(None, 2))
    if np.any((sensors <= 0) | (sensors >= 1)):
        raise ValueError("`sensors` must lie strictly inside the unit square (0, 1)^2")
    force_width = 0.125 if force_width is None else check_positive("force_width", force_width)
    if inclusion is not None:
        (cx, cy), cw = inclusion
        cw = check_positive("inclusion width", cw)

    x = np.linspace(0.0, 1.0, n_cells + 1)
    mesh = skfem.MeshTri.init_tensor(x, x)
    basis = skfem.Basis(mesh, skfem.ElementTriP1())
    interior = basis.complement_dofs(basis.get_dofs())

    def stiffness(weight):
        @skfem.BilinearForm
        def form(u, v, w):
            return weight(w.x[0], w.x[1]) * dot(grad(u), grad(v))

        return skfem.asm(form, basis)[interior][:, interior].tocsr()

    def phi(m):
        return lambda X, Y: np.cos(np.pi * m[0] * X) * np.cos(np.pi * m[1] * Y)

    def bump(x0, y0, s):
        return lambda X, Y: np.exp(-((X - x0) ** 2 + (Y - y0) ** 2) / (2 * s**2))

    K0 = stiffness(lambda X, Y: np.ones_like(X))
    Kb = None if inclusion is None else stiffness(bump(cx, cy, cw))
    if patches is None:
        mean_terms = [(K0, Coefficient.power10(0, sign=1.0, scale=a0), "a0")]
    else:
        m = check_int("patches", patches, minimum=1)
        mean_terms = []
        for p in range(m * m):
            ix, iy = p % m, p // m

            def indicator(X, Y, ix=ix, iy=iy):
                inside_x = np.minimum(np.floor(X * m), m - 1) == ix
                return (inside_x & (np.minimum(np.floor(Y * m), m - 1) == iy)).astype(float)

            coef = Coefficient.power10(p, sign=1.0, scale=a0)
            mean_terms.append((stiffness(indicator), coef, f"a0 patch {p}"))
    n_eps = len(mean_terms) + (Kb is not None)
    if Kb is not None:
        mean_terms.append((Kb, Coefficient.parameter(n_eps - 1), "inclusion"))
    K_modes = [
        stiffness(lambda X, Y, m=m, s=s: s * phi(m)(X, Y))
        for m, s in zip(modes, sigmas, strict=True)
    ]

    @skfem.LinearForm
    def unit_load(v, w):
        return 1.0 * v

    F = skfem.asm(unit_load, basis)[interior]

    def force(x0, y0):
        @skfem.LinearForm
        def form(v, w):
            return bump(x0, y0, force_width)(w.x[0], w.x[1]) * v

        return skfem.asm(form, basis)[interior]

    Gamma = np.column_stack([force(px, py) for px, py in sensors])
    M_obs = sp.csr_matrix(basis.probes(sensors.T))[:, interior]

    chaos = ChaosBasis(order, len(modes))
    terms = [LinearTerm(K, c, name=name) for K, c, name in mean_terms]
    for k, K in enumerate(K_modes):
        G = weighted_gram(chaos, lambda w, k=k: w[:, k] - 0.5)
        terms.append(LinearTerm(K, G=G, name=f"random mode {k + 1}"))
    terms.append(LoadTerm.constant(F))
    system = GalerkinSystem(terms, n_eps, basis=chaos, Gamma=Gamma, name="fem-diffusion")
    return FemDiffusion(
        system,
        chaos,
        mesh,
        basis,
        interior,
        sensors,
        M_obs,
        mean_terms,
        K0,
        Kb,
        K_modes,
        F,
        Gamma,
        a0,
    )
