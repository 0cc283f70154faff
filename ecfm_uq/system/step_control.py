"""The former home of the error-controlled grids, kept importable: they live in
:mod:`.time.grids`."""

from .time.grids import (
    MAX_RATIO,
    StepSequence,
    check_steps,
    check_tolerances,
    choose_steps,
    default_atol,
    step_errors,
)

__all__ = [
    "MAX_RATIO",
    "StepSequence",
    "check_steps",
    "check_tolerances",
    "choose_steps",
    "default_atol",
    "step_errors",
]
