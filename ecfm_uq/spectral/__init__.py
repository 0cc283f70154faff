"""Spatial discretization: bases, quadrature and Galerkin operators (paper Section 3)."""

from .basis import BeamBasis, SineBasis, SinusoidBasis, TensorBasis2D
from .operators import (
    gaussian_forces,
    gram,
    gram_vector,
    hat_forces,
    kron2,
    load,
    mass,
    project,
    rbf_forces,
    sensor_matrix,
    stiffness,
    triple,
)
from .quadrature import composite_gauss

__all__ = [
    "BeamBasis",
    "SineBasis",
    "SinusoidBasis",
    "TensorBasis2D",
    "composite_gauss",
    "gaussian_forces",
    "gram",
    "gram_vector",
    "hat_forces",
    "kron2",
    "load",
    "mass",
    "project",
    "rbf_forces",
    "sensor_matrix",
    "stiffness",
    "triple",
]
