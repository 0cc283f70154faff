"""The shape every formulation's fit has: a :class:`Fitter` and the :class:`Outcome` it returns.

Every fit of :func:`~ecfm_uq.inverse.fit` runs the same steps: check the options (by
name, before any model call), run an optimizer, measure the optimality conditions at the
returned point, compute the uncertainty and the verdict, and report formulation-specific
details. A :class:`Fitter` does the steps of one (problem kind, formulation) pair; its
:meth:`Fitter.run` returns an :class:`Outcome`, a frozen record of what was *measured*
(the point, the optimality conditions there, whether the budget ran out, a model
failure) and computed. It decides no status and builds no result: the entry point
(:mod:`ecfm_uq.inverse.fitting`) decides the status with
:func:`~ecfm_uq.inverse.core.convergence.decide_status` from the measurement and builds
the one frozen :class:`~ecfm_uq.inverse.InverseResult`, once.

A new formulation is one class (a subclass of :class:`Fitter`, in its own file) and one
row of :data:`ecfm_uq.inverse.fitting.FITTERS`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from .details import Details
from .result import Uncertainty, Verdict

__all__ = ["Fitter", "Outcome", "holds", "measured"]


def measured(out):
    """What a driver (:mod:`~ecfm_uq.inverse.core.drivers`) measured at its final point,
    as ``{"opt", "exhausted", "failure"}``: the optimality conditions (an
    :class:`~ecfm_uq.inverse.core.convergence.Optimality`, ``None`` where the model
    fails), whether the budget ran out, the model failure there."""
    return {"opt": out.opt, "exhausted": out.exhausted, "failure": out.final_error}


def holds(opt, failure=None):
    """Whether the optimality conditions were measured to hold at a point where the model
    can be solved (what :func:`~ecfm_uq.inverse.core.convergence.decide_status` calls
    CONVERGED): a fitter asks it to decide whether an uncertainty is worth computing."""
    return failure is None and opt is not None and bool(opt.converged)


@dataclass(frozen=True)
class Outcome:
    """What a :class:`Fitter` measured and computed; the entry point turns it into the
    :class:`~ecfm_uq.inverse.InverseResult` (same field names) after deciding the status.

    Attributes
    ----------
    eps : (n_eps,) ndarray
        The returned point.
    loss : float
    opt : Optimality or None
        The optimality conditions measured at ``eps`` (``None``: not measured, the model
        fails there; ``opt.value`` ``None`` where the test has no finite size).
    exhausted : bool
        Whether the optimizer's budget ran out.
    failure : Exception, str or None
        A model failure at ``eps``.
    label : str
        The formulation's label on the result (``result.formulation``).
    method : str
        The optimizer that ran.
    extra : Details
        The formulation's typed details (:mod:`~ecfm_uq.inverse.core.details`; the keys
        documented on :class:`~ecfm_uq.inverse.InverseResult`).
    solution : SteadySolution or None
        The model's solve at ``eps`` where the fit has it (the steady standard fit's), for
        a fit built on this one to reuse; not carried to the result.

    The other fields are the result's (``message``, ``nit``, ``nfev``, ``njev``, the
    histories, ``state``, ``forces``, ``uncertainty``, ``verdict``, ``likelihood``,
    ``interval_likelihood``, ``names``, ``problem``).
    """

    eps: np.ndarray
    loss: float
    opt: Any = None
    exhausted: bool = False
    failure: Any = None
    label: str = ""
    method: str = ""
    message: str = ""
    nit: int = 0
    nfev: int = 0
    njev: int = 0
    eps_history: np.ndarray | None = None
    loss_history: np.ndarray | None = None
    state: Any = None
    forces: Any = None
    uncertainty: Uncertainty = field(default_factory=lambda: Uncertainty(False))
    verdict: Verdict | None = None
    likelihood: Any = None
    interval_likelihood: Any = None
    names: list | None = None
    problem: Any = None
    extra: Details = field(default_factory=Details)
    solution: Any = field(default=None, repr=False)

    @property
    def optimality(self):
        """The measured optimality's unit-free size (``None`` when not measured)."""
        return None if self.opt is None else self.opt.value


class Fitter:
    """One formulation of one problem kind: the steps of its fit.

    Class attributes
    ----------------
    kind : str
        The problem kind (``"model"``, ``"ode"``, ``"steady"``, ``"dynamic"``,
        ``"replicated"``).
    formulation : str
        The formulation's name in ``fit(formulation=...)``.
    default_method : str
        What ``method="auto"`` runs.
    methods : tuple of str or None
        The methods it takes by name (``None``: it checks ``method`` itself).
    options : dict or None
        Its option names with their defaults (``None``: it checks ``options`` itself,
        before any model call).

    Subclasses implement :meth:`run`; :meth:`check_options` runs first, before any model
    call, and refuses an unknown option by name.
    """

    kind: ClassVar[str] = ""
    formulation: ClassVar[str] = ""
    default_method: ClassVar[str] = "auto"
    methods: ClassVar[tuple | None] = None
    options: ClassVar[dict | None] = None

    def method(self, settings):
        """The method that runs (``"auto"`` read as :attr:`default_method`).

        Raises
        ------
        ValueError
            A method this fitter has not (when :attr:`methods` names them).
        """
        method = self.default_method if settings.method == "auto" else settings.method
        if self.methods is not None and method not in self.methods:
            raise ValueError(
                f"unknown `method` {settings.method!r} for formulation="
                f"{settings.formulation!r} of a {self.kind} problem; choose one of "
                f"{list(self.methods)}"
            )
        return method

    def check_options(self, problem, settings):
        """``settings.options`` completed by :attr:`options`' defaults, checked by name
        before any model call (:meth:`~ecfm_uq.inverse.core.settings.FitSettings.take`);
        ``problem`` is there for the checks that need its size (no model call).

        Raises
        ------
        TypeError
            An option this fitter does not know, named.
        """
        self.method(settings)
        if self.options is None:
            return dict(settings.options)
        return settings.take(self.options)

    def run(self, problem, eps0, settings):
        """Fit ``problem`` from ``eps0`` with the validated ``settings``; an
        :class:`Outcome` (no status: the entry point decides it)."""
        raise NotImplementedError
