"""The former home of :class:`GalerkinSystem`, kept importable: it lives in
:mod:`.model.galerkin`."""

from .model.galerkin import GalerkinSystem

__all__ = ["GalerkinSystem"]
