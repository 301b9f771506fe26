"""The SO(3) helpers against independent references: numpy's cross product, scipy's rotations and
finite differences of the exponential map."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from arm.so3 import left_jacobian, rot_x, rot_y, rot_z, rotation_matrix, rotation_vector, skew

RNG = np.random.default_rng(3)


def test_skew_is_the_cross_product():
    v, u = RNG.normal(size=(5, 3)), RNG.normal(size=(5, 3))
    np.testing.assert_allclose(np.einsum("nij,nj->ni", skew(v), u), np.cross(v, u), atol=1e-15)
    np.testing.assert_array_equal(skew(v[0]), -skew(v[0]).T)


@pytest.mark.parametrize(("fn", "axis"), [(rot_x, 0), (rot_y, 1), (rot_z, 2)])
def test_elementary_rotations_match_scipy(fn, axis):
    a = RNG.uniform(-np.pi, np.pi, 7)
    ref = Rotation.from_euler("xyz"[axis], a[:, None]).as_matrix()
    np.testing.assert_allclose(fn(a), ref, atol=1e-15)
    np.testing.assert_allclose(fn(float(a[0])), ref[0], atol=1e-15)
    assert fn(a.reshape(7, 1)).shape == (7, 1, 3, 3)


def test_rotation_matrix_and_vector_batch_shapes_and_round_trip():
    r = RNG.normal(scale=0.8, size=(4, 2, 3))
    R = rotation_matrix(r)
    assert R.shape == (4, 2, 3, 3)
    np.testing.assert_allclose(
        R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape), atol=1e-14
    )
    np.testing.assert_allclose(rotation_vector(R), r, atol=1e-12)


@pytest.mark.parametrize("scale", [0.0, 1e-9, 1e-3, 0.5, 2.5])
def test_left_jacobian_by_finite_differences(scale):
    r = RNG.normal(size=3)
    r = scale * r / np.linalg.norm(r)
    h = 1e-6
    J = np.empty((3, 3))
    R0 = rotation_matrix(r)
    for i in range(3):
        dr = np.zeros(3)
        dr[i] = h
        plus = rotation_vector(rotation_matrix(r + dr) @ R0.T)
        minus = rotation_vector(rotation_matrix(r - dr) @ R0.T)
        J[:, i] = (plus - minus) / (2 * h)
    np.testing.assert_allclose(left_jacobian(r), J, atol=1e-8)
