"""What a Galerkin system's terms imply for its solvers, computed once per system.

A :class:`~ecfm_uq.system.GalerkinSystem` is immutable: its terms are bound at
construction and never change. Everything the solvers derive from them (linearity,
sparsity, the decoupling of the couplings, the germ's Gauss nodes, the stacked
operators and node tables of the compiled kernels, the triple products' nonzero pairs,
the mass matrices) is therefore a property of the system, computed on first use and kept
in one :class:`SystemStructure` that the system owns (``system.structure``). No other
object writes onto the system; the solve plan (:mod:`..solve.plan`) reads its decisions from
here.
"""

from __future__ import annotations

from functools import cached_property

import numpy as np
import scipy.sparse as sp

from ...memory import check_allocation
from .nonlinear_term import NonlinearTerm
from .terms import LinearTerm, QuadraticTerm, _symmetric

__all__ = ["SystemStructure", "triple_product_pairs"]


def triple_product_pairs(E3):
    """The chaos pairs ``(b, c)`` that :math:`\\mathbb E[\\Psi_a\\Psi_b\\Psi_c]` couples.

    Returns ``(bs, cs, W)``: the structurally nonzero pairs and ``W`` (n_pairs, P) with
    ``W[m, a] = E3[a, bs[m], cs[m]]``, so a projected quadratic form costs one
    evaluation per pair (paper Eq. pce, quadratic term).
    """
    E3 = np.asarray(E3, dtype=float)
    bs, cs = np.nonzero(np.any(E3 != 0.0, axis=0))
    W = E3[:, bs, cs].T
    for a in (bs, cs, W):
        a.setflags(write=False)
    return bs, cs, W


class SystemStructure:
    """The structure of one :class:`~ecfm_uq.system.GalerkinSystem` (see the module).

    Every attribute is computed on first use and then fixed, as the system is.
    """

    def __init__(self, system, pairs=None):
        self._system = system
        self.pairs = pairs  # (bs, cs, W) of the triple products, None without quadratic terms
        self._operator = None  # (key, op): a linear system's Jacobian operator at (eps, dt)
        self._mass = {}
        self._mass_dt = {}

    # -- terms ---------------------------------------------------------------------------
    @cached_property
    def linear_terms(self):
        """The :class:`LinearTerm` s, in order (a tuple)."""
        return tuple(t for t in self._system.terms if isinstance(t, LinearTerm))

    @cached_property
    def quadratic_terms(self):
        """The :class:`QuadraticTerm` s, in order (a tuple)."""
        return tuple(t for t in self._system.terms if isinstance(t, QuadraticTerm))

    @property
    def n_quadratic(self):
        return len(self.quadratic_terms)

    @cached_property
    def nonlinear_terms(self):
        """The user's :class:`NonlinearTerm` s, in order (a tuple)."""
        return tuple(t for t in self._system.terms if isinstance(t, NonlinearTerm))

    @cached_property
    def is_linear(self):
        """No term is quadratic (or a user's nonlinear term) in the state."""
        return not self.quadratic_terms and not self.nonlinear_terms

    @cached_property
    def sparse_input(self):
        """Any spatial operator, ``M`` or ``Gamma`` is ``scipy.sparse``."""
        s = self._system
        return any(t.sparse for t in self.linear_terms) or sp.issparse(s.M) or sp.issparse(s.Gamma)

    # -- symmetry ------------------------------------------------------------------------
    @cached_property
    def mass_symmetric(self):
        """``M`` is symmetric."""
        return self._system.M is not None and _symmetric(self._system.M)

    @cached_property
    def _term_asymmetry(self):
        if self.nonlinear_terms:
            return f"term {self.nonlinear_terms[0].name!r} is a NonlinearTerm (symmetry unknown)"
        if not self.is_linear:
            return "the system has a quadratic (nonsymmetric) term"
        for term in self.linear_terms:
            if not term.is_symmetric():
                return f"term {term.name!r} has a non-symmetric K or G"
        return None

    def asymmetry(self, steady=True):
        """``None`` if the Jacobian (of a steady solve or a march step) is symmetric, else why not."""
        if self._term_asymmetry is not None:
            return self._term_asymmetry
        if not steady and self._system.M is not None and not self.mass_symmetric:
            return "the mass matrix M is not symmetric"
        return None

    # -- the chaos couplings ---------------------------------------------------------------
    @cached_property
    def decoupling(self):
        """``(Q, D)`` with every linear coupling :math:`G_q = Q D_q Q^T`, or ``None``.

        ``None`` for nonlinear systems, ``P = 1`` or couplings without a common eigenbasis
        (see :meth:`GalerkinSystem.decoupling`).
        """
        from ...chaos.tensors import common_eigenbasis

        if self._system.P == 1 or not self.is_linear:
            return None
        return common_eigenbasis([t.G for t in self.linear_terms])

    @cached_property
    def couplings_decouple(self):
        """The linear couplings and :math:`\\mathbb E[\\Psi\\Psi^T]` share an eigenbasis
        (the ``"decoupled"`` preconditioner applies)."""
        from ...chaos.tensors import common_eigenbasis

        s = self._system
        Gs = [t.G for t in self.linear_terms]
        return s.P > 1 and common_eigenbasis([*Gs, s.E2]) is not None

    @cached_property
    def gauss_nodes(self):
        """The one-germ basis at its ``P``-node Gauss rule (:class:`ecfm_uq.chaos.GaussNodes`),
        or ``None`` for ``P = 1`` or several germs."""
        from ...chaos.tensors import GaussNodes

        s = self._system
        one_germ = s.basis is not None and s.basis.dim == 1 and s.P > 1
        return GaussNodes(s.basis) if one_germ else None

    # -- tables of the compiled marches ------------------------------------------------------
    @cached_property
    def stacked_K(self):
        """The linear terms' operators as one dense (n_linear, N, N) array."""
        N = self._system.N
        dense = [t.K.toarray() if t.sparse else t.K for t in self.linear_terms]
        return np.array(dense, dtype=float).reshape(len(dense), N, N)

    @cached_property
    def nodal_tables(self):
        """``(Gs, gnode, mnode, E3m)`` of the compiled ``P > 1`` march.

        ``Gs`` (n_linear, P, P) the couplings, ``gnode`` (n_linear, P) and ``mnode`` (P,)
        their and :math:`\\mathbb E[\\Psi\\Psi^T]`'s values at the Gauss nodes, ``E3m``
        (P, P * P) the triple products as row ``c``, column ``b P + l``.
        """
        s = self._system
        P = s.P
        nodes = self.gauss_nodes
        lin = self.linear_terms
        Gs = np.array([t.G for t in lin], dtype=float).reshape(len(lin), P, P)
        gnode = np.array([nodes.coupling_values(G) for G in Gs]).reshape(len(lin), P)
        E3m = np.zeros((P, P * P))
        if self.quadratic_terms:
            E3m = np.ascontiguousarray(s.E3.transpose(1, 0, 2).reshape(P, P * P))
        return Gs, gnode, nodes.coupling_values(s.E2), E3m

    # -- mass --------------------------------------------------------------------------------
    def mass_matrix(self, sparse=False):
        """:math:`M\\otimes\\mathbb E[\\Psi\\Psi^T]`, dense or CSR, built once."""
        s = self._system
        kind = "sparse" if sparse else "dense"
        if kind not in self._mass:
            if sparse:
                self._mass[kind] = sp.kron(s.M, sp.csr_matrix(s.E2.T), format="csr")
            else:
                n = s.N * s.P
                check_allocation(
                    8.0 * n * n,
                    f"the dense mass matrix of {s.name!r} (NP = {n})",
                    "pass a sparse M and solver='cg' or 'gmres'",
                )
                M = s.M.toarray() if sp.issparse(s.M) else s.M
                self._mass[kind] = np.kron(M, s.E2.T)
        return self._mass[kind]

    def mass_over_dt(self, dt):
        """The dense :math:`M\\otimes\\mathbb E[\\Psi\\Psi^T]/\\Delta t` of the latest ``dt``
        (fixed during a march: divided once, not per Newton step)."""
        if dt not in self._mass_dt:
            self._mass_dt.clear()
            self._mass_dt[dt] = self.mass_matrix() / dt
        return self._mass_dt[dt]

    # -- a linear system's Jacobian ------------------------------------------------------------
    def cached_operator(self, key):
        """The operator stored for ``key`` by :meth:`store_operator`, or ``None``."""
        if self._operator is not None and self._operator[0] == key:
            return self._operator[1]
        return None

    def store_operator(self, key, op):
        """Keep a linear system's Jacobian operator for ``key = (eps bytes, dt)``, so that a
        solver sees the same object again and reuses its factors."""
        self._operator = (key, op)
