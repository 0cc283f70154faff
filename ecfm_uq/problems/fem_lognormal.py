"""2-D diffusion with a lognormal random conductivity, stochastic Galerkin in Hermite chaos.

The classic stochastic-Galerkin benchmark (Ghanem & Spanos; Elman et al. 2011; Ullmann
2010) on scikit-fem P1 triangles:

.. math::

    -\\nabla\\cdot\\bigl(a(x,\\xi)\\nabla u\\bigr) = 1 \\ \\text{in } (0,1)^2,
    \\qquad u = 0 \\text{ on the boundary}, \\qquad
    a(x, \\xi) = 10^{\\epsilon_0}\\exp\\bigl(g(x, \\xi)\\bigr),

    g(x, \\xi) = m + \\sum_{k=1}^{d} \\sqrt{\\lambda_k}\\,\\phi_k(x)\\,\\xi_k,
    \\qquad \\xi \\sim N(0, I_d),

a Gaussian field of mean :math:`m` and covariance :math:`s^2\\rho(|x - y|/\\ell)`
truncated to its first :math:`d` Karhunen-Loeve modes. The modes are a **discrete KL**
computed on the mesh: the Galerkin (P1) discretization of the covariance operator's
eigenproblem, :math:`M C M \\phi = \\lambda M \\phi`, with :math:`C_{ij} = s^2\\rho(|x_i -
x_j|/\\ell)` on the mesh nodes and :math:`M` the P1 mass matrix (so :math:`\\phi_k` are
P1 fields, :math:`M`-orthonormal).

The conductivity is expanded exactly in Hermite chaos (:func:`ecfm_uq.chaos.
lognormal_coefficients`), :math:`a = \\sum_\\alpha a_\\alpha(x)\\phi_\\alpha(\\xi)`, with
the coefficient basis of total order :math:`2p` for a solution of order :math:`p` (the
higher terms are orthogonal to every product of two order-:math:`p` terms, so the
coupling is exact). Each coefficient term gives one sparse stiffness
:math:`K_\\alpha = \\int a_\\alpha\\nabla u\\cdot\\nabla v` and one term
:math:`K_\\alpha \\otimes \\mathbb E[\\phi_\\alpha\\Psi\\Psi^T]` (paper Eq. pce):

.. math::

    R = 10^{\\epsilon_0}\\sum_\\alpha K_\\alpha\\,\\Theta\\,T_\\alpha
        - F\\,\\mathbb E[\\Psi]^T, \\qquad
    T_\\alpha = \\mathbb E[\\phi_\\alpha\\Psi\\Psi^T].

Discretization, once for every method: :math:`g` is the P1 interpolant of the modes and
:math:`a = e^g` is evaluated at the element quadrature points of the stiffness (the
same points for the chaos coefficients and for a deterministic sample), so the
deterministic model at a germ point :math:`\\xi` (:meth:`FemLognormal.stiffness`,
:meth:`FemLognormal.deterministic_system`) is exactly the model whose chaos the Galerkin
system truncates: Monte Carlo and collocation over it converge to the same moments.

This module only builds systems; solving is the engine's job. It needs the ``fem``
extra: ``pip install "ecfm-uq[fem]"``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .._validation import as_finite_array, check_choice, check_int, check_positive, check_real
from ..chaos import ChaosBasis, coupling_tensor, lognormal_coefficients
from ..memory import check_allocation
from ..system import Coefficient, GalerkinSystem, LinearTerm, LoadTerm
from .fem_diffusion import _skfem

__all__ = ["COVARIANCES", "FemLognormal", "build_fem_lognormal", "kl_expansion"]

#: Correlation functions rho(r / l) of the Gaussian field.
COVARIANCES = {
    "exponential": lambda t: np.exp(-t),
    "squared-exponential": lambda t: np.exp(-0.5 * t**2),
}

# dense generalized eigenproblem below this many nodes, Lanczos (eigsh) above
_DENSE_KL_NODES = 1500


def kl_expansion(points, mass, n_kl, *, sigma, corr_length, covariance="exponential"):
    """Discrete Karhunen-Loeve modes of a stationary Gaussian field on P1 nodes.

    Parameters
    ----------
    points : (n, 2) ndarray
        Mesh nodes.
    mass : (n, n) scipy.sparse matrix
        P1 mass matrix on those nodes.
    n_kl : int
        Number of modes, ``1 <= n_kl <= n``.
    sigma : float
        Standard deviation :math:`s \\ge 0` of the field.
    corr_length : float
        Correlation length :math:`\\ell > 0`.
    covariance : {"exponential", "squared-exponential"}
        :math:`\\rho(t) = e^{-t}` or :math:`e^{-t^2/2}`, :math:`t = |x - y|/\\ell`.

    Returns
    -------
    values : (n_kl,) ndarray
        Eigenvalues :math:`\\lambda_k`, descending (0 when ``sigma = 0``).
    modes : (n, n_kl) ndarray
        :math:`\\phi_k` at the nodes, :math:`\\phi^T M \\phi = I`, each signed so that
        its largest-magnitude nodal value is positive.

    Notes
    -----
    Galerkin discretization of :math:`\\int C(x, y)\\phi(y)\\,dy = \\lambda\\phi(x)` with
    :math:`C` replaced by its P1 x P1 interpolant: :math:`M C M\\phi = \\lambda M\\phi`.
    Over all ``n`` modes the eigenvalues sum to :math:`\\operatorname{tr}(CM) =
    \\int c_h(x, x)\\,dx`, :math:`c_h` the P1 x P1 interpolant of the covariance; it
    tends to the field's total variance :math:`s^2|D|` as the mesh is refined (from below:
    the interpolant lies under :math:`s^2` on the diagonal inside the elements), so
    :math:`\\sum_{k \\le d}\\lambda_k / (s^2|D|)` is the variance fraction the truncation
    keeps, up to that discretization error.
    """
    points = as_finite_array("points", points, shape=(None, 2))
    n = points.shape[0]
    n_kl = check_int("n_kl", n_kl, minimum=1)
    if n_kl > n:
        raise ValueError(f"`n_kl` must be at most the number of mesh nodes {n}, got {n_kl}")
    sigma = check_real("sigma", sigma)
    if sigma < 0:
        raise ValueError(f"`sigma` must be >= 0 (the field's standard deviation), got {sigma}")
    corr_length = check_positive("corr_length", corr_length)
    rho = COVARIANCES[check_choice("covariance", covariance, tuple(COVARIANCES))]
    check_allocation(
        3 * 8.0 * n * n,
        f"the dense ({n}, {n}) nodal covariance of the KL eigenproblem",
        "use a coarser mesh",
    )
    if sigma == 0:
        return np.zeros(n_kl), np.zeros((n, n_kl))
    r = np.sqrt(((points[:, None, :] - points[None, :, :]) ** 2).sum(axis=-1))
    C = sigma**2 * rho(r / corr_length)
    del r
    M = sp.csr_matrix(mass)
    MCM = M @ (M @ C).T  # C symmetric: (M C)^T = C M
    MCM = 0.5 * (MCM + MCM.T)
    if n <= _DENSE_KL_NODES or n_kl > n // 3:
        values, modes = sla.eigh(MCM, M.toarray(), subset_by_index=[n - n_kl, n - 1])
    else:
        values, modes = spla.eigsh(MCM, k=n_kl, M=M.tocsc(), which="LA", tol=1e-12)
    order = np.argsort(values)[::-1]
    values, modes = np.maximum(values[order], 0.0), modes[:, order]
    # M-normalize (eigsh's are already, to its tolerance) and fix each sign
    modes = modes / np.sqrt(np.einsum("ik,ik->k", modes, M @ modes))
    big = modes[np.argmax(np.abs(modes), axis=0), np.arange(n_kl)]
    return values, modes * np.sign(big)


@dataclass
class FemLognormal:
    """The assembled lognormal-diffusion model.

    Attributes
    ----------
    system : GalerkinSystem
        Stochastic system in Hermite chaos, ``n_eps = 1`` (:math:`\\epsilon_0`: the
        conductivity is :math:`10^{\\epsilon_0}e^{g}`, i.e. a shift of the field's mean by
        :math:`\\epsilon_0\\ln 10`), state (N, P) on the interior nodes; one
        :class:`LinearTerm` per coefficient chaos term.
    chaos : ChaosBasis
        The solution's Hermite basis, order p, ``dim = n_kl``.
    coef_basis : ChaosBasis
        The conductivity's Hermite basis (order ``coef_order``, default 2p).
    mesh, fem_basis
        scikit-fem mesh and P1 basis.
    interior : (N,) ndarray
        Mesh node indices of the unknowns.
    F : (N,) ndarray
        Load vector of f = 1.
    K_terms : list of (N, N) csr_matrix
        :math:`K_\\alpha = \\int a_\\alpha(x)\\nabla u\\cdot\\nabla v`, one per
        ``coef_basis`` term (at :math:`\\epsilon_0 = 0`).
    mass : (N, N) csr_matrix
        P1 mass matrix on the unknowns (for L2 norms of interior fields).
    kl_values : (n_kl,) ndarray
        KL eigenvalues :math:`\\lambda_k`.
    kl_modes : (n_nodes, n_kl) ndarray
        KL modes :math:`\\phi_k` at every mesh node.
    kl_fraction : float
        Variance fraction kept, :math:`\\sum_k\\lambda_k / s^2` (the domain has area 1);
        ``nan`` for ``sigma = 0``.
    mean, sigma, corr_length : float
    covariance : str
    """

    system: GalerkinSystem
    chaos: ChaosBasis
    coef_basis: ChaosBasis
    mesh: object
    fem_basis: object
    interior: np.ndarray
    F: np.ndarray
    K_terms: list
    mass: sp.csr_matrix
    kl_values: np.ndarray
    kl_modes: np.ndarray
    kl_fraction: float
    mean: float
    sigma: float
    corr_length: float
    covariance: str
    _loadings: np.ndarray = field(repr=False)  # (n_elem, n_qp, n_kl) sqrt(lam) phi at qp
    _dx: np.ndarray = field(repr=False)  # (n_elem, n_qp) quadrature weights
    _assembly: tuple = field(repr=False)  # (map (nnz, n_elem), indices, indptr)

    @property
    def n_kl(self):
        """Number of germ variables (KL modes)."""
        return self.kl_values.size

    @property
    def n_nodes(self):
        """Mesh nodes (boundary included)."""
        return self.mesh.p.shape[1]

    def _check_xi(self, xi):
        xi = as_finite_array("xi", np.atleast_1d(xi), shape=(self.n_kl,))
        return xi

    def _matrix(self, weights):
        emap, indices, indptr = self._assembly
        N = self.interior.size
        return sp.csr_matrix((emap @ weights, indices, indptr), shape=(N, N))

    def log_conductivity(self, xi):
        """:math:`g(x, \\xi)` at every mesh node, (n_nodes,), for a germ point ``xi`` (n_kl,)."""
        xi = self._check_xi(xi)
        return self.mean + self.kl_modes @ (np.sqrt(self.kl_values) * xi)

    def stiffness(self, xi, eps0=0.0):
        """:math:`K(\\xi) = \\int 10^{\\epsilon_0} e^{g(x,\\xi)}\\nabla u\\cdot\\nabla v`, (N, N) csr.

        The deterministic model at one germ point (a Monte Carlo or collocation sample),
        on the same quadrature points as the chaos terms, so that
        :math:`K(\\xi) = \\sum_\\alpha K_\\alpha\\phi_\\alpha(\\xi)` as the coefficient
        order grows.
        """
        xi = self._check_xi(xi)
        eps0 = check_real("eps0", eps0)
        a = np.exp(self.mean + self._loadings @ xi)
        return (10.0**eps0) * self._matrix(np.sum(a * self._dx, axis=1))

    def deterministic_system(self, xi):
        """The ``P = 1`` system at germ point ``xi`` (n_kl,): one sample, same ``n_eps``."""
        K = self.stiffness(xi)
        terms = [
            LinearTerm(K, Coefficient.power10(0, sign=1.0), name="lognormal at xi"),
            LoadTerm.constant(self.F),
        ]
        return GalerkinSystem(terms, 1, name="fem-lognormal (sample)")

    def nodal(self, values):
        """Interior values (N,) -> values at every mesh node (zero on the boundary)."""
        out = np.zeros(self.n_nodes)
        out[self.interior] = values
        return out


def _p1_assembly(basis, interior, n_nodes):
    """Sparse map from per-element weights w_T to the CSR data of sum_T w_T K_T^unit.

    P1 gradients are constant on a triangle, so :math:`\\int_T a\\nabla\\phi_i\\cdot
    \\nabla\\phi_j = (\\int_T a)\\,\\nabla\\phi_i\\cdot\\nabla\\phi_j`: every stiffness of this
    model is this map applied to the element integrals of its coefficient.
    """
    dofs = basis.element_dofs  # (3, n_elem)
    n_elem = dofs.shape[1]
    grads = np.stack([basis.basis[i][0].grad[:, :, 0] for i in range(3)])  # (3, 2, n_elem)
    local = np.einsum("idt,jdt->ijt", grads, grads)  # (3, 3, n_elem)
    where = np.full(n_nodes, -1)
    where[interior] = np.arange(interior.size)
    rows = np.broadcast_to(where[dofs][:, None, :], (3, 3, n_elem)).ravel()
    cols = np.broadcast_to(where[dofs][None, :, :], (3, 3, n_elem)).ravel()
    elem = np.broadcast_to(np.arange(n_elem), (3, 3, n_elem)).ravel()
    keep = (rows >= 0) & (cols >= 0)
    N = interior.size
    key = rows[keep].astype(np.int64) * N + cols[keep]
    pattern, slot = np.unique(key, return_inverse=True)  # sorted: CSR order
    emap = sp.csr_matrix((local.ravel()[keep], (slot, elem[keep])), shape=(pattern.size, n_elem))
    indices = (pattern % N).astype(np.int32)
    indptr = np.searchsorted(pattern // N, np.arange(N + 1)).astype(np.int32)
    return emap, indices, indptr


def build_fem_lognormal(
    n_cells=16,
    order=3,
    n_kl=4,
    *,
    mean=0.0,
    sigma=0.5,
    corr_length=0.5,
    covariance="exponential",
    coef_order=None,
):
    """Assemble the lognormal-diffusion problem in Hermite chaos.

    Parameters
    ----------
    n_cells : int
        Cells per side of a uniform triangulation of the unit square
        (``(n_cells + 1)^2`` nodes, ``(n_cells - 1)^2`` unknowns).
    order : int
        Total order p of the solution's Hermite chaos (``P = C(n_kl + p, p)``).
    n_kl : int
        Karhunen-Loeve modes kept, i.e. germ variables.
    mean : float
        Mean :math:`m` of the Gaussian field :math:`g = \\log a`.
    sigma : float
        Standard deviation :math:`s \\ge 0` of :math:`g` (before truncation); ``0`` gives
        the deterministic conductivity :math:`e^m`.
    corr_length : float
        Correlation length :math:`\\ell`.
    covariance : {"exponential", "squared-exponential"}
        :math:`s^2 e^{-r/\\ell}` or :math:`s^2 e^{-r^2/(2\\ell^2)}`.
    coef_order : int, optional
        Order of the conductivity's Hermite chaos. Default ``2 * order``: the lowest
        order at which the Galerkin coupling is exact (lower truncates the coefficient,
        higher adds terms that couple nothing).

    Returns
    -------
    FemLognormal
    """
    skfem = _skfem()

    n_cells = check_int("n_cells", n_cells, minimum=2)
    order = check_int("order", order, minimum=0)
    n_kl = check_int("n_kl", n_kl, minimum=1)
    mean = check_real("mean", mean)
    coef_order = 2 * order if coef_order is None else check_int("coef_order", coef_order, minimum=0)

    x = np.linspace(0.0, 1.0, n_cells + 1)
    mesh = skfem.MeshTri.init_tensor(x, x)
    basis = skfem.Basis(mesh, skfem.ElementTriP1())
    interior = basis.complement_dofs(basis.get_dofs())
    n_nodes = mesh.p.shape[1]

    mass_form = skfem.BilinearForm(lambda u, v, w: u * v)
    M_full = skfem.asm(mass_form, basis).tocsr()
    values, modes = kl_expansion(
        mesh.p.T, M_full, n_kl, sigma=sigma, corr_length=corr_length, covariance=covariance
    )
    sigma = float(sigma)
    fraction = float(values.sum() / sigma**2) if sigma > 0 else float("nan")

    # sqrt(lam_k) phi_k at the stiffness's quadrature points
    loadings = np.stack(
        [np.asarray(basis.interpolate(np.sqrt(values[k]) * modes[:, k])) for k in range(n_kl)],
        axis=-1,
    )
    dx = np.asarray(basis.dx)
    emap, indices, indptr = _p1_assembly(basis, interior, n_nodes)
    N = interior.size

    chaos = ChaosBasis(order, n_kl, germ="hermite")
    coef_basis = ChaosBasis(coef_order, n_kl, germ="hermite")
    Pa = coef_basis.size
    check_allocation(
        8.0 * (loadings.shape[0] * loadings.shape[1] * Pa + emap.shape[0] * Pa),
        f"the {Pa} chaos terms of the conductivity at {loadings.shape[0]} elements",
        "lower `order` (or `coef_order`), `n_kl` or the mesh",
    )
    # element integrals of every chaos coefficient a_alpha(x): (n_elem, Pa)
    A = lognormal_coefficients(coef_basis, loadings, mean=mean)  # (n_elem, n_qp, Pa)
    W = np.einsum("eqa,eq->ea", A, dx)
    del A
    data = emap @ W  # (nnz, Pa)
    K_terms = [sp.csr_matrix((data[:, a], indices, indptr), shape=(N, N)) for a in range(Pa)]
    T = coupling_tensor(coef_basis, chaos)  # (Pa, P, P)

    eps_coef = Coefficient.power10(0, sign=1.0)
    terms = []
    for a in range(Pa):
        if not np.any(T[a]):
            continue  # orthogonal to every product of two solution terms
        name = "a_" + "".join(str(int(i)) for i in coef_basis.indices[a])
        terms.append(LinearTerm(K_terms[a], eps_coef, G=T[a], name=name))
    F = skfem.asm(skfem.LinearForm(lambda v, w: 1.0 * v), basis)[interior]
    terms.append(LoadTerm.constant(F))
    system = GalerkinSystem(terms, 1, basis=chaos, name="fem-lognormal")
    return FemLognormal(
        system=system,
        chaos=chaos,
        coef_basis=coef_basis,
        mesh=mesh,
        fem_basis=basis,
        interior=interior,
        F=F,
        K_terms=K_terms,
        mass=M_full[interior][:, interior].tocsr(),
        kl_values=values,
        kl_modes=modes,
        kl_fraction=fraction,
        mean=mean,
        sigma=sigma,
        corr_length=float(corr_length),
        covariance=covariance,
        _loadings=loadings,
        _dx=dx,
        _assembly=(emap, indices, indptr),
    )
