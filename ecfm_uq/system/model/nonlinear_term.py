"""A user's deterministic nonlinearity, projected onto the chaos basis by a Gauss rule.

The user supplies the spatial residual of a nonlinear term and its Jacobian for one
realization of the germ, ``residual(u, omega, eps) -> (N,)`` and
``jacobian(u, omega, eps) -> (N, N)`` (dense or ``scipy.sparse``), e.g. a reaction
:math:`u^3` or a conductivity :math:`k(u)` assembled by scikit-fem. The Galerkin term is
its pseudo-spectral projection (Xiu 2010, ch. 6; Constantine, Gleich & Iaccarino 2009)
with a rule :math:`(\\omega_q, w_q)` of the germ,

.. math::

    R_{ik}(\\Theta) = \\sum_q w_q\\, r_i(u_q, \\omega_q, \\epsilon)\\,\\Psi_k(\\omega_q),
    \\qquad u_q = \\Theta\\,\\Psi(\\omega_q),

    \\frac{\\partial R_{ik}}{\\partial \\Theta_{jl}}
        = \\sum_q w_q\\, J_{ij}(u_q, \\omega_q, \\epsilon)\\,\\Psi_k(\\omega_q)\\Psi_\\ell(\\omega_q),

exact when the integrands are polynomials of the rule's degree.

Exactness of the rules: for a nonlinearity of degree ``m`` in ``u`` and a state of chaos
order ``p``, :math:`r\\Psi_k` and :math:`J\\Psi_k\\Psi_\\ell` have degree :math:`D = (m + 1)p`.
The tensor rule with :math:`n = \\lceil (D + 1)/2 \\rceil` Gauss points per germ is exact
to degree :math:`2n - 1 \\ge D` in each germ. The Gauss Smolyak rule of level ``L``
combines tensor rules of :math:`l_i` points with :math:`\\sum_i l_i \\le L + d`; a
monomial :math:`\\omega^\\alpha` is integrated exactly if some rule has
:math:`2 l_i - 1 \\ge \\alpha_i`, i.e. :math:`\\sum_i (\\lfloor\\alpha_i/2\\rfloor + 1) \\le L + d`,
which holds for every total degree :math:`|\\alpha| \\le D` when :math:`L = \\lfloor D/2 \\rfloor`
(checked against the tensor rule in ``tests/system/test_nonlinear_term.py``).
"""

from __future__ import annotations

import copy
import math

import numpy as np
import scipy.sparse as sp

from ..._validation import check_int, is_sparse
from ..._validation import describe as _describe

__all__ = ["MAX_RULE_NODES", "NonlinearTerm", "nonlinear_rule_points"]

# a tensor rule larger than this is refused (each node costs a residual and a Jacobian
# evaluation of the user's model per Newton step)
MAX_RULE_NODES = 20_000


def nonlinear_rule_points(order, degree):
    """Gauss points per germ that integrate a degree-``degree`` nonlinearity exactly.

    With the state of chaos order ``p``, :math:`r(u)\\Psi_k` is of degree
    :math:`(\\text{degree} + 1)\\,p` per germ and a ``n``-point Gauss rule integrates
    degree :math:`2n - 1`: ``n = ceil(((degree + 1) p + 1) / 2)`` (``2p + 1`` for a
    cubic, ``ceil((3p + 1)/2)`` for a quadratic nonlinearity, what
    :class:`QuadraticTerm`'s exact triple products correspond to). The Jacobian's
    integrand :math:`r'(u)\\Psi_k\\Psi_\\ell` has the same degree.
    """
    return max(1, math.ceil(((degree + 1) * order + 1) / 2))


def _smolyak_size(level, dim):
    """An upper bound of the Smolyak grid's node count: the sizes of its tensor rules,
    :math:`\\sum_{\\ell + 1 \\le |l| \\le \\ell + d} \\prod_i l_i`, by a recursion on the
    level sums (no enumeration of the multi-levels)."""
    top = level + dim
    sums = np.zeros(top + 1)  # sums[s]: sum of prod(l) over the l of the germs so far, |l| = s
    sums[0] = 1.0
    for _ in range(dim):
        new = np.zeros(top + 1)
        for li in range(1, level + 2):
            new[li:] += li * sums[: top + 1 - li]
        sums = new
    return float(sums[level + 1 : top + 1].sum())


def smolyak_quadrature(level, basis):
    """The Gauss Smolyak rule of ``level`` for the basis' germs, as (nodes, weights).

    The combination of the tensor rules of :func:`ecfm_uq.chaos.smolyak_rule`, summed on
    its distinct nodes (weights may be negative; they sum to one).
    """
    from ...chaos import smolyak_rule

    nodes, parts = smolyak_rule(level, basis.dim, "gauss", basis.germs)
    if len(nodes) > MAX_RULE_NODES:
        raise ValueError(
            f"the Smolyak rule of level {level} in {basis.dim} germs has {len(nodes)} nodes "
            f"(> {MAX_RULE_NODES}); lower the chaos order or `degree`"
        )
    weights = np.zeros(len(nodes))
    for coef, _levels, idx, w, _degrees in parts:
        np.add.at(weights, idx, coef * w)
    return nodes, weights


def _model_error(message):
    from ...errors import ModelEvaluationError

    return ModelEvaluationError(message)


class NonlinearTerm:
    """A user's deterministic nonlinear term :math:`r(u, \\omega, \\epsilon)` in the Galerkin system.

    Parameters
    ----------
    residual : callable
        ``residual(u, omega, eps) -> (N,)``: the term's contribution to the spatial
        residual for the state ``u`` (N,) at the germ point ``omega`` (dim,) (empty for a
        deterministic system) and parameters ``eps`` (n_eps,).
    jacobian : callable
        ``jacobian(u, omega, eps) -> (N, N)``: :math:`\\partial r/\\partial u`, a dense
        array or a ``scipy.sparse`` matrix.
    eps_jacobian : callable, optional
        ``eps_jacobian(u, omega, eps) -> (N, n_eps)``: :math:`\\partial r/\\partial\\epsilon`,
        needed for parameter sensitivities and calibration. ``None`` means unknown (a
        sensitivity then raises ``ValueError`` naming this term), not zero; pass
        ``lambda u, w, e: np.zeros((len(u), len(e)))`` for a term without parameters.
    degree : int
        Polynomial degree of the nonlinearity in ``u`` (with any dependence on
        ``omega`` counted in): the ``"auto"``/``"tensor"`` rule takes
        :func:`nonlinear_rule_points` ``(p, degree)`` Gauss points per germ, which is
        exact for polynomial terms of that degree. Default 3 (a cubic reaction:
        ``2p + 1`` points). For non-polynomial terms (``exp(u)``) raise it until the
        answer stops changing.
    rule : "auto", "tensor", "smolyak", int or (nodes, weights)
        ``"tensor"``: the tensor Gauss rule of the basis' germs (``ChaosBasis.quadrature``)
        with the points above; ``"smolyak"``: the Gauss Smolyak rule of level
        :math:`\\lfloor(\\text{degree} + 1)\\,p/2\\rfloor`, exact for the same polynomial
        integrands of total degree (several germs); ``"auto"``: whichever of the two has
        fewer nodes. An ``int``: that many tensor points per germ; a pair
        ``(nodes (Q, dim), weights (Q,))``: the user's own rule, weights summing to one.
    size : int, optional
        The state size N, needed only when the system has no other term that fixes it.
    name : str

    Notes
    -----
    Each Newton step evaluates ``residual`` and ``jacobian`` once per rule node.
    The system treats the term as nonlinear and non-symmetric; the compiled marches and
    the ``"nodal"`` and ``"decoupled"`` solvers do not take it (the generic Newton path
    with a dense, sparse or mean-preconditioned Krylov solve does).
    """

    def __init__(
        self,
        residual,
        jacobian,
        *,
        eps_jacobian=None,
        degree=3,
        rule="auto",
        size=None,
        name="nonlinear",
    ):
        for arg, f in (("residual", residual), ("jacobian", jacobian)):
            if not callable(f):
                raise TypeError(
                    f"`{arg}` must be callable {arg}(u, omega, eps), got {_describe(f)}"
                )
        if eps_jacobian is not None and not callable(eps_jacobian):
            raise TypeError(
                "`eps_jacobian` must be callable eps_jacobian(u, omega, eps) or None, "
                f"got {_describe(eps_jacobian)}"
            )
        self.residual = residual
        self.jacobian = jacobian
        self.eps_jacobian_fn = eps_jacobian
        self.degree = check_int("degree", degree, minimum=1)
        if isinstance(rule, str):
            if rule not in ("auto", "tensor", "smolyak"):
                raise ValueError(
                    "`rule` must be 'auto', 'tensor', 'smolyak', an int or (nodes, weights), "
                    f"got {rule!r}"
                )
        elif isinstance(rule, int | np.integer) and not isinstance(rule, bool):
            check_int("rule", rule, minimum=1)
        elif not (isinstance(rule, tuple | list) and len(rule) == 2):
            raise TypeError(
                "`rule` must be 'auto', 'tensor', 'smolyak', an int or (nodes, weights), "
                f"got {_describe(rule)}"
            )
        self.rule = rule
        self.size = None if size is None else check_int("size", size, minimum=1)
        self.name = name

    # -- binding ---------------------------------------------------------------------------
    def _make_rule(self, basis):
        if basis is None:  # deterministic: one point, no germ
            return np.zeros((1, 0)), np.ones(1), np.ones((1, 1))
        if isinstance(self.rule, tuple | list):
            nodes = np.asarray(self.rule[0], dtype=float)
            weights = np.asarray(self.rule[1], dtype=float)
            if nodes.ndim == 1 and basis.dim == 1:
                nodes = nodes[:, None]
            if nodes.ndim != 2 or nodes.shape[1] != basis.dim or weights.shape != (len(nodes),):
                raise ValueError(
                    f"term {self.name!r}: `rule` must be (nodes (Q, {basis.dim}), weights (Q,)), "
                    f"got shapes {nodes.shape} and {weights.shape}"
                )
            if not np.all(np.isfinite(weights)) or abs(weights.sum() - 1.0) > 1e-10:
                raise ValueError(
                    f"term {self.name!r}: the rule's weights must be finite probability "
                    f"weights summing to 1, got sum {weights.sum():.6g}"
                )
        else:
            nodes, weights = self._gauss_rule(basis)
        Psi = basis.evaluate(nodes)  # validates the nodes against the germs' supports
        return nodes, weights, Psi

    def _gauss_rule(self, basis):
        """The tensor or Smolyak Gauss rule the term's ``rule`` and ``degree`` ask for."""
        n = self.rule if not isinstance(self.rule, str) else None
        if n is None:
            n = nonlinear_rule_points(basis.order, self.degree)
        total = n**basis.dim
        smolyak = None
        if self.rule in ("auto", "smolyak") and basis.dim > 1:
            # a total-degree integrand of degree D = (degree + 1) p_max is integrated
            # exactly by the Gauss Smolyak rule of level floor(D / 2) (module docstring)
            p_max = int(basis.indices.sum(axis=1).max())
            level = ((self.degree + 1) * p_max) // 2
            size = _smolyak_size(level, basis.dim)
            if self.rule == "smolyak" or size < min(total, 4 * MAX_RULE_NODES):
                smolyak = smolyak_quadrature(level, basis)
        if smolyak is not None:
            return smolyak
        if total > MAX_RULE_NODES:
            raise ValueError(
                f"term {self.name!r}: the tensor Gauss rule has {n}^{basis.dim} = {total} "
                f"nodes (> {MAX_RULE_NODES}); pass rule='smolyak' or rule=(nodes, weights), "
                "a smaller `degree`, or fewer germs"
            )
        return basis.quadrature(n)

    def bind(self, basis, N, n_eps):
        """A copy bound to a system's basis (``None``: deterministic), state size and
        ``n_eps``; ``self`` is unchanged."""
        if self.size is not None and self.size != N:
            raise ValueError(
                f"term {self.name!r}: `size`={self.size} but the system's state has N={N}"
            )
        bound = copy.copy(self)
        bound._nodes, bound._weights, bound._Psi = self._make_rule(basis)
        bound._wPsi = bound._weights[:, None] * bound._Psi  # (Q, P)
        bound._N, bound._n_eps = N, n_eps
        bound._last = None  # (Theta, eps, node residuals) of the latest evaluation
        return bound

    @property
    def n_nodes(self):
        """Number of rule nodes Q (bound terms only)."""
        return len(self._weights)

    @property
    def nodes(self):
        """The rule's germ nodes (Q, dim) and probability weights (Q,) (bound terms only)."""
        return self._nodes, self._weights

    # -- evaluation of the callbacks -------------------------------------------------------
    def _node_states(self, Theta):
        return np.asarray(Theta) @ self._Psi.T  # (N, Q): column q is u(omega_q)

    def _call(self, which, f, u, q, eps):
        omega = self._nodes[q] if isinstance(q, int | np.integer) else q
        try:
            with np.errstate(over="raise", invalid="raise", divide="raise"):
                out = f(u, omega, eps)
        except (OverflowError, FloatingPointError, ZeroDivisionError) as e:
            raise _model_error(
                f"term {self.name!r}: `{which}` failed at omega={omega.tolist()} "
                f"({type(e).__name__}: {e})"
            ) from e
        return out

    def _checked(self, which, A, shape, meaning, q):
        """A callback's answer ``A``: of ``shape`` (else a ValueError naming the callback
        and what the shape means) and finite (else a model error naming the node)."""
        if A.shape != shape:
            square = len(A.shape) == 2 and A.shape[0] == A.shape[1]
            what = (
                "a non-square " if len(shape) == 2 and shape[0] == shape[1] and not square else ""
            )
            raise ValueError(
                f"term {self.name!r}: `{which}`(u, omega, eps) returned {what}shape {A.shape}, "
                f"expected {shape} ({meaning})"
            )
        if not np.all(np.isfinite(A.data if is_sparse(A) else A)):
            omega = self._nodes[q] if np.ndim(q) == 0 else q
            raise _model_error(
                f"term {self.name!r}: `{which}` returned NaN or inf at "
                f"omega={np.asarray(omega).tolist()}"
            )
        return A

    def _residual_at(self, u, q, eps):
        r = self._call("residual", self.residual, u, q, eps)
        try:
            r = np.asarray(r, dtype=float)
        except (TypeError, ValueError) as e:
            raise TypeError(
                f"term {self.name!r}: `residual` must return numbers, got {_describe(r)}"
            ) from e
        meaning = "N, the state size; return one entry per unknown"
        return self._checked("residual", r, (self._N,), meaning, q)

    def _jacobian_at(self, u, q, eps):
        """``jacobian`` at rule node ``q`` (an index) or at a germ point ``q`` (an array)."""
        J = self._call("jacobian", self.jacobian, u, q, eps)
        if is_sparse(J):
            J = sp.csr_matrix(J, dtype=float)
        else:
            try:
                J = np.asarray(J, dtype=float)
            except (TypeError, ValueError) as e:
                raise TypeError(
                    f"term {self.name!r}: `jacobian` must return an array or a scipy.sparse "
                    f"matrix, got {_describe(J)}"
                ) from e
        N = self._N
        return self._checked("jacobian", J, (N, N), "dr/du, square in the state size N", q)

    def _eps_jacobian_at(self, u, q, eps):
        if self.eps_jacobian_fn is None:
            raise ValueError(
                f"term {self.name!r}: parameter sensitivities need its derivative in eps; "
                "pass NonlinearTerm(..., eps_jacobian=f) with f(u, omega, eps) -> (N, n_eps)"
            )
        D = self._call("eps_jacobian", self.eps_jacobian_fn, u, q, eps)
        D = D.toarray() if is_sparse(D) else np.asarray(D, dtype=float)
        return self._checked("eps_jacobian", D, (self._N, len(eps)), "N, n_eps", q)

    # -- the term's interface --------------------------------------------------------------
    def node_residuals(self, Theta, eps):
        """:math:`r(u_q, \\omega_q, \\epsilon)` at every rule node, (N, Q).

        The last evaluation is kept: Newton asks for the residual and its round-off scale
        (:meth:`magnitude`) at the same state, which costs one pass over the nodes.
        """
        Theta = np.asarray(Theta, dtype=float)
        eps = np.asarray(eps, dtype=float)
        last = self._last
        if last is not None and np.array_equal(last[0], Theta) and np.array_equal(last[1], eps):
            return last[2]
        U = self._node_states(Theta)
        R = np.column_stack([self._residual_at(U[:, q], q, eps) for q in range(self.n_nodes)])
        self._last = (Theta.copy(), eps.copy(), R)
        return R

    def apply(self, Theta, eps, t=None):
        return self.node_residuals(Theta, eps) @ self._wPsi

    def magnitude(self, Theta, eps):
        """The round-off scale of :meth:`apply`: :math:`\\sum_q w_q |r_q| |\\Psi(\\omega_q)|`."""
        return np.abs(self.node_residuals(Theta, eps)) @ np.abs(self._wPsi)

    def node_jacobians(self, Theta, eps):
        """:math:`\\partial r/\\partial u` at every rule node (a list of Q matrices).

        Dense Jacobians at all Q nodes are held at once: refused
        (:class:`~ecfm_uq.errors.MemoryBudgetError`) beyond the memory budget.
        """
        U = self._node_states(Theta)
        first = self._jacobian_at(U[:, 0], 0, eps)
        if not is_sparse(first) and self.n_nodes > 1:
            from ...memory import check_allocation

            check_allocation(
                8.0 * self._N**2 * self.n_nodes,
                f"term {self.name!r}: dense Jacobians at {self.n_nodes} rule nodes (N = {self._N})",
                "return a scipy.sparse matrix from `jacobian`",
            )
        rest = [self._jacobian_at(U[:, q], q, eps) for q in range(1, self.n_nodes)]
        return [first, *rest]

    def linearize(self, Theta, eps):
        """The term's Jacobian at ``Theta`` as an operator part (see :mod:`.operator`)."""
        return _NonlinearLinearization(self, self.node_jacobians(Theta, eps), Theta, eps)

    def eps_jacobian(self, Theta, eps, t=None):
        U = self._node_states(Theta)
        n_eps = len(eps)
        D = np.zeros((self._N, self._Psi.shape[1], n_eps))
        for q in range(self.n_nodes):
            D += self._eps_jacobian_at(U[:, q], q, eps)[:, None, :] * self._wPsi[q][None, :, None]
        return D.reshape(-1, n_eps)

    def eps_vjp(self, Theta, eps, mu, t=None):
        """:math:`(\\partial R/\\partial\\epsilon)^T\\mu` without the (NP, n_eps) matrix."""
        U = self._node_states(Theta)
        mu = np.reshape(mu, (self._N, self._Psi.shape[1]))
        g = np.zeros(len(eps))
        M = mu @ self._wPsi.T  # (N, Q): mu projected on each node
        for q in range(self.n_nodes):
            g += self._eps_jacobian_at(U[:, q], q, eps).T @ M[:, q]
        return g


class _NonlinearLinearization:
    """The Jacobian of a :class:`NonlinearTerm` at a fixed state:
    :math:`\\sum_q J_q \\otimes w_q\\Psi(\\omega_q)\\Psi(\\omega_q)^T`."""

    is_quadratic = True  # state-dependent: solvers treat it as the nonlinear parts
    is_user = True

    def __init__(self, term, Js, Theta, eps):
        self.term, self.Js = term, Js
        self.Theta, self.eps = Theta, eps
        self.coef = 1.0
        self.sparse_input = any(is_sparse(J) for J in Js)

    def apply(self, X):
        Xq = X @ self.term._Psi.T  # (N, Q)
        Y = np.column_stack([np.asarray(J @ Xq[:, q]) for q, J in enumerate(self.Js)])
        return Y @ self.term._wPsi

    def apply_transpose(self, Y):
        Yq = Y @ self.term._wPsi.T  # (N, Q)
        X = np.column_stack([np.asarray(J.T @ Yq[:, q]) for q, J in enumerate(self.Js)])
        return X @ self.term._Psi

    def magnitude(self, X):
        Xq = np.abs(X) @ np.abs(self.term._Psi.T)
        Y = np.column_stack([np.asarray(abs(J) @ Xq[:, q]) for q, J in enumerate(self.Js)])
        return Y @ np.abs(self.term._wPsi)

    def _coupling(self, q):
        return np.outer(self.term._Psi[q], self.term._wPsi[q])  # [k, l]: w Psi_k Psi_l

    def dense(self):
        N, P = self.term._N, self.term._Psi.shape[1]
        J = np.zeros((N * P, N * P))
        for q, Jq in enumerate(self.Js):
            Jq = Jq.toarray() if is_sparse(Jq) else Jq
            J += np.kron(Jq, self._coupling(q))
        return J

    def sparse(self):
        out = None
        for q, Jq in enumerate(self.Js):
            block = sp.kron(sp.csr_matrix(Jq), sp.csr_matrix(self._coupling(q)), format="csr")
            out = block if out is None else out + block
        return out

    def kronecker_terms(self):
        """``[(J_q, w_q Psi_q Psi_q^T)]``: :meth:`apply` ``= sum_q J_q X C_q``."""
        return [(Jq, self._coupling(q)) for q, Jq in enumerate(self.Js)]

    def node_block(self, omega, u):
        """The deterministic Jacobian at germ point ``omega`` (dim,) and state ``u`` (N,)
        (a block of the ``"nodal"`` preconditioner)."""
        return self.term._jacobian_at(u, np.atleast_1d(omega), self.eps)

    def mean_block(self, E2_00):
        """The (0, 0) chaos block over :math:`\\mathbb E[\\Psi_0^2]`."""
        w0 = self.term._wPsi[:, 0] * self.term._Psi[:, 0] / E2_00
        K = None
        for q, Jq in enumerate(self.Js):
            K = w0[q] * Jq if K is None else K + w0[q] * Jq
        return K
