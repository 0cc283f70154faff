"""Spatial operators against closed forms and independent quadrature."""

import numpy as np
import pytest
from scipy import integrate

from ecfm_uq.spectral import (
    BeamBasis,
    SineBasis,
    TensorBasis2D,
    gram,
    hat_forces,
    load,
    mass,
    project,
    rbf_forces,
    sensor_matrix,
    stiffness,
    triple,
)


def test_sine_mass_and_stiffness_are_diagonal_closed_form():
    n = 12
    b = SineBasis(n)
    k = np.pi * np.arange(1, n + 1)
    np.testing.assert_allclose(mass(b), np.eye(n) / 2, atol=1e-13)
    np.testing.assert_allclose(stiffness(b), np.diag(k**2 / 2), rtol=1e-12, atol=1e-10)


def test_beam_modes_operators_closed_form():
    n = 8
    b = BeamBasis(n)
    k = np.pi * (2 * np.arange(1, n + 1) - 1) / 2
    np.testing.assert_allclose(mass(b), np.eye(n) / 2, atol=1e-13)
    np.testing.assert_allclose(stiffness(b), np.diag(k**2 / 2), rtol=1e-12, atol=1e-10)
    np.testing.assert_allclose(
        gram(b, derivatives=(2, 2)), np.diag(k**4 / 2), rtol=1e-12, atol=1e-8
    )
    # boundary conditions built into the basis: f(0) = f''(0) = f'(1) = f'''(1) = 0
    for d, x in [(0, 0.0), (2, 0.0), (1, 1.0), (3, 1.0)]:
        np.testing.assert_allclose(b.evaluate([x], d), 0.0, atol=1e-10)


def _delta(p):
    return (p == 0).astype(float)


def test_convection_tensor_closed_form():
    # int_0^1 sin(i pi x) sin(j pi x) k pi cos(k pi x) dx by product-to-sum identities
    n = 7
    A = triple(SineBasis(n), (0, 0, 1))
    i, j, k = np.meshgrid(*(np.arange(1, n + 1),) * 3, indexing="ij")
    exact = (
        0.25
        * k
        * np.pi
        * (_delta(i - j - k) + _delta(i - j + k) - _delta(i + j - k) - _delta(i + j + k))
    )
    np.testing.assert_allclose(A, exact, atol=1e-12)


def test_load_of_constant_source():
    n = 9
    F = load(SineBasis(n), lambda x: np.ones_like(x))
    i = np.arange(1, n + 1)
    np.testing.assert_allclose(F, (1 - np.cos(i * np.pi)) / (i * np.pi), atol=1e-14)


def test_load_with_jump_uses_breakpoints():
    b = SineBasis(5)
    s = lambda x: np.where(x > 0.3, 2.0, 0.0)
    F = load(b, s, breakpoints=(0.3,))
    ref = [2 * integrate.quad(lambda x, i=i: np.sin(i * np.pi * x), 0.3, 1)[0] for i in range(1, 6)]
    np.testing.assert_allclose(F, ref, atol=1e-13)


def test_project_recovers_a_basis_function():
    b = SineBasis(6)
    c = project(b, lambda x: 3 * np.sin(2 * np.pi * x))
    np.testing.assert_allclose(c, [0, 3, 0, 0, 0, 0], atol=1e-13)


def test_hat_forces_against_adaptive_quadrature():
    b = SineBasis(4)
    G = hat_forces(b, [0.2, 0.5], 0.2)
    for j, xc in enumerate([0.2, 0.5]):
        for i in range(4):
            f = lambda x, i=i, xc=xc: np.sin((i + 1) * np.pi * x) * max(0.0, 1 - abs(x - xc) / 0.2)
            ref = integrate.quad(f, 0, 1, points=[xc - 0.2, xc, xc + 0.2])[0]
            assert abs(G[i, j] - ref) < 1e-12


def test_rbf_forces_factorize_like_a_2d_integral():
    bx = SineBasis(3)
    basis = TensorBasis2D(bx, SineBasis(2))
    centers = np.array([[0.3, 0.6], [0.5, 0.5]])
    G = rbf_forces(basis, centers, omega=50.0)
    x = np.linspace(0, 1, 1601)
    w = np.full_like(x, x[1] - x[0])
    w[[0, -1]] /= 2
    X, Y = np.meshgrid(x, x, indexing="ij")
    for j, (cx, cy) in enumerate(centers):
        g = 50.0 / np.pi * np.exp(-50.0 * ((X - cx) ** 2 + (Y - cy) ** 2))
        for a in range(3):
            for bb in range(2):
                f = np.sin((a + 1) * np.pi * X) * np.sin((bb + 1) * np.pi * Y)
                ref = w @ (f * g) @ w
                assert abs(G[a * 2 + bb, j] - ref) < 1e-6


def test_tensor_basis_evaluation_is_a_product():
    basis = TensorBasis2D(SineBasis(3), BeamBasis(2))
    pts = np.array([[0.1, 0.7], [0.4, 0.2]])
    V = basis.evaluate(pts)
    for m, (x, y) in enumerate(pts):
        for a in range(3):
            for bb in range(2):
                ref = np.sin((a + 1) * np.pi * x) * np.sin((2 * bb + 1) * np.pi * y / 2)
                assert abs(V[m, a * 2 + bb] - ref) < 1e-14


def test_sensor_matrix_values_and_bad_points():
    b = SineBasis(3)
    M = sensor_matrix(b, [0.25, 0.5])
    np.testing.assert_allclose(M[1], [1, 0, -1], atol=1e-15)
    with pytest.raises(ValueError, match="points"):
        sensor_matrix(b, [0.5, 1.5])
    with pytest.raises(ValueError, match="points"):
        sensor_matrix(b, [np.nan])
    with pytest.raises(ValueError, match="points"):
        sensor_matrix(TensorBasis2D(b), [[0.5, -0.1]])


def test_bad_arguments_name_themselves():
    with pytest.raises(ValueError, match="n"):
        SineBasis(0)
    with pytest.raises(TypeError, match="n"):
        SineBasis(2.5)
    with pytest.raises(ValueError, match="half_width"):
        hat_forces(SineBasis(2), [0.5], -0.1)
    with pytest.raises(TypeError, match="s"):
        load(SineBasis(2), 3.0)
    with pytest.raises(ValueError, match="weight"):
        gram(SineBasis(2), weight=lambda x: np.full_like(x, np.nan))
