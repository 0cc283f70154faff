"""Exceptions raised by ecfm_uq."""


class ConvergenceError(RuntimeError):
    """An iterative solver did not converge and the caller asked for strictness."""


class SingularSystemError(ValueError):
    """A system matrix is singular or indefinite where it must not be (e.g. buckling)."""
