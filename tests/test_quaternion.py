"""Quaternion identities (scalar first, Hamilton product, body -> navigation)."""
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from pdr import quaternion as quat

finite = st.floats(-1.0, 1.0, allow_nan=False)
vec4 = arrays(np.float64, 4, elements=finite).filter(lambda v: np.linalg.norm(v) > 0.1)
vec3 = arrays(np.float64, 3, elements=st.floats(-10, 10, allow_nan=False))


def _as_pure(v):
    return np.r_[0.0, v]


@settings(max_examples=200, deadline=None)
@given(vec4, vec4, vec4)
def test_product_is_associative_and_norm_multiplicative(a, b, c):
    left = quat.multiply(quat.multiply(a, b), c)
    right = quat.multiply(a, quat.multiply(b, c))
    assert np.allclose(left, right, atol=1e-12)
    assert np.isclose(np.linalg.norm(quat.multiply(a, b)), np.linalg.norm(a) * np.linalg.norm(b))


@settings(max_examples=200, deadline=None)
@given(vec4)
def test_conjugate_is_inverse_of_unit_quaternion(q):
    q = quat.normalize(q)
    assert np.allclose(quat.multiply(q, quat.conjugate(q)), quat.IDENTITY, atol=1e-12)
    assert np.allclose(quat.multiply(quat.conjugate(q), q), quat.IDENTITY, atol=1e-12)


@settings(max_examples=200, deadline=None)
@given(vec4, vec3)
def test_rotation_matches_sandwich_products(q, v):
    """rotate = q ⊗ v ⊗ q*, rotate_inverse = q* ⊗ v ⊗ q (the predicted body measurement)."""
    q = quat.normalize(q)
    fwd = quat.multiply(quat.multiply(q, _as_pure(v)), quat.conjugate(q))[1:]
    inv = quat.multiply(quat.multiply(quat.conjugate(q), _as_pure(v)), q)[1:]
    assert np.allclose(quat.rotate(q, v), fwd, atol=1e-9)
    assert np.allclose(quat.rotate_inverse(q, v), inv, atol=1e-9)
    assert np.allclose(quat.rotate_inverse(q, quat.rotate(q, v)), v, atol=1e-9)


@settings(max_examples=100, deadline=None)
@given(vec4)
def test_matrix_round_trip_and_angle(q):
    q = quat.normalize(q)
    back = quat.from_matrix(quat.to_matrix(q))
    assert min(np.abs(back - q).max(), np.abs(back + q).max()) < 1e-9
    assert np.isclose(quat.angle(q), quat.angle(-q))  # q and -q are one rotation
    assert 0.0 <= quat.angle(q) <= np.pi + 1e-12


def test_axis_angle_and_composition_of_yaws():
    a = quat.from_axis_angle([0, 0, 1], 0.3)
    b = quat.from_yaw(0.5)
    assert np.isclose(quat.angle(a), 0.3)
    assert np.isclose(quat.yaw(quat.multiply(a, b)), 0.8)
    assert np.allclose(quat.from_rotation_vector(np.array([0.0, 0.0, 0.3])), a)
    assert np.allclose(quat.from_rotation_vector(np.zeros(3)), quat.IDENTITY)
    # a quarter turn about z takes the body x axis to nav y
    assert np.allclose(quat.rotate(quat.from_yaw(np.pi / 2), [1.0, 0, 0]), [0, 1.0, 0], atol=1e-12)


def test_error_angle_is_the_angle_between_orientations():
    q1 = quat.from_axis_angle([1, 2, 3], 0.4)
    q2 = quat.multiply(q1, quat.from_axis_angle([0, 1, 0], np.radians(7)))
    assert np.isclose(np.degrees(quat.angle_between(q2, q1)), 7.0)


def test_orientation_from_gravity_and_field():
    q_true = quat.from_axis_angle([0.3, -0.2, 1.0], 1.1)
    g = quat.rotate_inverse(q_true, [0, 0, 9.81])
    m = quat.rotate_inverse(q_true, [0, 20.0, -44.0])
    assert np.degrees(quat.angle_between(q_true, quat.from_two_vectors(g, m, north_axis=1))) < 1e-6


@settings(max_examples=100, deadline=None)
@given(vec4, vec4)
def test_left_matrix_is_left_multiplication(p, q):
    assert np.allclose(quat.left_matrix(p) @ q, quat.multiply(p, q), atol=1e-12)
