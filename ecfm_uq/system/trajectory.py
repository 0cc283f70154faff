"""The former home of :class:`Trajectory`, kept importable: it lives in
:mod:`.model.trajectory`."""

from .model.trajectory import Trajectory, generic_adjoint

__all__ = ["Trajectory", "generic_adjoint"]
