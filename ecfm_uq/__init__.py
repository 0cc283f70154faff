"""ecfm_uq: polynomial chaos stochastic Galerkin engine and the explicit constraint
force method (ECFM) for inverse problems.

Layers, in the direction data flows:

``chaos``      germ, shifted-Legendre basis, quadrature, expectation tensors
``spectral``   spatial bases, operators M K A F, sensors, constraint-force shapes
``system``     the Galerkin system R(Theta; eps, lam), Newton, time stepping, sensitivities
``inverse``    standard, ECFM, noisy and pseudo-likelihood formulations, optimizers
``problems``   Burgers, Fisher-KPP, beam, heat: systems built from the paper's equations
``studies``    one module per paper section, writing result.json and figures
"""

__version__ = "0.5.0.dev0"
