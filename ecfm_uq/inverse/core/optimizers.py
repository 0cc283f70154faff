"""First-order optimizers for the reduced (unconstrained) inverse problems.

The paper minimizes both dynamic objectives of Section 3.1 (Eqs. inv_obj and ecfm_obj,
reduced to functions of :math:`\\epsilon` by sensitivity analysis) with Adam, learning
rate :math:`10^{-2}`, for 250 epochs. Adam is Kingma and Ba (2015), Algorithm 1:

.. math::

    m_k = \\beta_1 m_{k-1} + (1 - \\beta_1) g_k,\\quad
    v_k = \\beta_2 v_{k-1} + (1 - \\beta_2) g_k^2,\\quad
    \\epsilon_{k} = \\epsilon_{k-1}
        - \\alpha\\,\\frac{m_k / (1 - \\beta_1^k)}{\\sqrt{v_k / (1 - \\beta_2^k)} + \\hat\\varepsilon}.

Its steps have size about :math:`\\alpha` per component whatever the scale of the loss,
so the number of epochs needed grows with the distance from the start to the optimum.
"""

from __future__ import annotations

import numbers

import numpy as np

from ..._validation import as_finite_array, check_int, check_positive
from ...errors import ConvergenceError
from .convergence import decide_status, minimize_optimality
from .details import DynamicDetails
from .drivers import Outcome
from .result import InverseResult

__all__ = ["adam", "run_adam"]


def adam(
    fun_and_grad,
    x0,
    lr=1e-2,
    epochs=250,
    betas=(0.9, 0.999),
    eps_hat=1e-8,
    *,
    formulation="adam",
    callback=None,
    gtol=1e-10,
):
    """Minimize ``fun_and_grad`` with Adam for a fixed number of epochs.

    Parameters
    ----------
    fun_and_grad : callable
        ``fun_and_grad(x) -> (f, g)`` with ``f`` a float and ``g`` an ``(n,)`` array. It
        may raise :class:`ecfm_uq.errors.ConvergenceError` when an inner solve fails; the
        optimization then stops with ``success=False`` and that message.
    x0 : (n,) array_like
        Starting point.
    lr : float
        Learning rate :math:`\\alpha`.
    epochs : int
        Number of Adam updates (>= 1).
    betas : (float, float)
        Decay rates :math:`(\\beta_1, \\beta_2)`, each in [0, 1).
    eps_hat : float
        :math:`\\hat\\varepsilon` in the denominator.
    formulation : str
        Label stored in the result (``result.formulation``) (e.g. ``"standard"`` or ``"ecfm"``).
    callback : callable, optional
        ``callback(epoch, x, f, g)`` after each evaluation (epoch 0 is the start).
    gtol : float
        Tolerance of the optimality measured at the final iterate
        (:func:`~ecfm_uq.inverse.core.convergence.minimize_optimality`: the gradient
        relative to the objective at ``x0``, or the round-off limit).

    Returns
    -------
    InverseResult
        ``eps`` is the final iterate and ``loss`` the objective there;
        ``eps_history`` ``(epochs + 1, n)`` and ``loss_history`` ``(epochs + 1,)`` hold
        every iterate and its loss; ``extra["grad"]`` is the final gradient and
        ``extra["grad_history"]`` all gradients. On a failed evaluation the histories
        stop at the last successful iterate, which is returned with ``success=False``.
        The status is decided here, once, from what :func:`run_adam` measured at the
        final iterate (:func:`~ecfm_uq.inverse.core.convergence.decide_status`):
        CONVERGED when its optimality holds (``optimality`` is the measured value), else
        MAX_ITERATIONS (the epochs are a budget, not a test); MODEL_FAILURE on a failed
        evaluation.

    Raises
    ------
    ConvergenceError
        If the objective already fails at ``x0`` (there is no iterate to return).
    """
    out = run_adam(
        fun_and_grad, x0, lr=lr, epochs=epochs, betas=betas, eps_hat=eps_hat,
        label=formulation, callback=callback, gtol=gtol,
    )  # fmt: skip
    return InverseResult(
        eps=out.x,
        loss=out.loss,
        status=decide_status(out.opt, out.exhausted, out.final_error),
        optimality=out.optimality,
        message=out.message,
        nit=out.nit,
        nfev=out.nfev,
        njev=out.nfev,
        formulation=formulation,
        method="adam",
        eps_history=out.eps_history,
        loss_history=out.loss_history,
        extra=out.payload,
    )


def run_adam(fun_and_grad, x0, *, lr=1e-2, epochs=250, betas=(0.9, 0.999), eps_hat=1e-8,
             label="adam", callback=None, gtol=1e-10):  # fmt: skip
    """Adam's iterations (the arguments of :func:`adam`; ``label`` names the objective in
    the error raised at ``x0``) and what is measured at the final iterate, as a driver
    reports it: no status.

    Returns
    -------
    ~ecfm_uq.inverse.core.drivers.Outcome
        ``x`` the final iterate, ``loss`` and ``grad`` there, ``nit`` the epochs run,
        ``nfev`` the evaluations (each gives the gradient too), the histories of every
        iterate; ``opt`` the optimality measured there
        (:func:`~ecfm_uq.inverse.core.convergence.minimize_optimality`; ``None`` after a
        failed evaluation), ``exhausted`` always (the epochs are a budget),
        ``final_error`` the failed evaluation (the histories stop at the last successful
        iterate); ``payload`` a :class:`~.details.DynamicDetails` ``(grad,
        grad_history)`` (the final gradient and every gradient: :func:`adam`'s ``extra``).

    Raises
    ------
    ConvergenceError
        If the objective already fails at ``x0`` (there is no iterate to return).
    """
    if not callable(fun_and_grad):
        raise TypeError("`fun_and_grad` must be callable x -> (f, g)")
    x = as_finite_array("x0", np.atleast_1d(x0), ndim=1).copy()
    lr = check_positive("lr", lr)
    gtol = check_positive("gtol", gtol)
    epochs = check_int("epochs", epochs, minimum=1)
    try:
        b1, b2 = (float(b) for b in betas)
    except (TypeError, ValueError) as e:
        raise TypeError("`betas` must be a pair of floats (beta1, beta2)") from e
    if not (0.0 <= b1 < 1.0 and 0.0 <= b2 < 1.0):
        raise ValueError(f"`betas` must lie in [0, 1), got {betas}")
    if not isinstance(eps_hat, numbers.Real) or eps_hat < 0 or not np.isfinite(eps_hat):
        raise ValueError(f"`eps_hat` must be a finite number >= 0, got {eps_hat!r}")

    m = np.zeros_like(x)
    v = np.zeros_like(x)
    xs, fs, gs = [], [], []
    message = f"completed {epochs} epochs"
    failure = None
    for k in range(epochs + 1):
        try:
            f, g = fun_and_grad(x)
            f = float(f)
            g = np.asarray(g, dtype=float).reshape(x.shape)
            if not (np.isfinite(f) and np.all(np.isfinite(g))):
                raise ConvergenceError(f"objective or gradient is not finite (f={f}, g={g})")
        except ConvergenceError as e:
            failure = e
            message = f"evaluation failed at epoch {k} (eps={np.array2string(x)}): {e}"
            break
        xs.append(x.copy())
        fs.append(f)
        gs.append(g)
        if callback is not None:
            callback(k, x.copy(), f, g)
        if k == epochs:
            break
        t = k + 1
        m = b1 * m + (1.0 - b1) * g
        v = b2 * v + (1.0 - b2) * g * g
        mhat = m / (1.0 - b1**t)
        vhat = v / (1.0 - b2**t)
        x = x - lr * mhat / (np.sqrt(vhat) + eps_hat)

    if not xs:
        raise ConvergenceError(f"{label}: the objective fails at the starting point: {message}")
    opt = None
    if failure is None:
        message += f"; final |grad| = {np.linalg.norm(gs[-1]):.3e}"
        scale = fs[0] if fs[0] > 0 else 1.0
        opt = minimize_optimality(gs[-1], xs[-1], fs[-1], scale, gtol, None)
    return Outcome(
        xs[-1], fs[-1], gs[-1], DynamicDetails(grad=gs[-1], grad_history=np.array(gs)), message,
        len(xs) - 1, len(xs) + (failure is not None), np.array(xs), np.array(fs),
        final_error=failure, opt=opt, exhausted=True,
    )  # fmt: skip
