"""Exceptions raised by ecfm_uq."""


class ConvergenceError(RuntimeError):
    """An iterative solver did not converge and the caller asked for strictness."""


class KrylovError(ConvergenceError):
    """A Krylov solve did not reach its tolerance (the message gives iterations and residual)."""


class SingularSystemError(ValueError):
    """A system matrix is singular or indefinite where it must not be (e.g. buckling)."""


class MemoryBudgetError(MemoryError):
    """A requested allocation exceeds the memory budget (see :mod:`ecfm_uq.memory`).

    Raised *before* allocating; the message gives the size needed, the budget and the
    options that avoid the allocation.
    """


class ModelEvaluationError(ConvergenceError):
    """The model could not be evaluated at the given parameters (overflow, NaN, inf).

    E.g. a coefficient :math:`10^{\\epsilon_m}` overflows at a huge :math:`\\epsilon_m`.
    Solvers turn it into a reported failure (``success=False``); inverse fits treat it like
    a failed inner solve. The message names the term and the parameters.
    """


class NonIdentifiableError(ValueError):
    """The data do not determine a combination of the parameters.

    Raised where an estimate's information matrix (the derivative of its optimality
    condition in :math:`\\epsilon`) is singular: the message names the combination of
    parameters (the null vector) that the data leave free, instead of returning a NaN
    or astronomically large covariance. ``null_vector`` holds it, unit length.
    """

    def __init__(self, message, null_vector=None):
        super().__init__(message)
        self.null_vector = null_vector
