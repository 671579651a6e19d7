"""Eq. (4) and (5) against first principles: the sum of r_i x F_i."""

from __future__ import annotations

import numpy as np
import pytest

from tiltrov_ros.core.thrust_map import (
    allocation_matrix,
    q_vector,
    thrust_wrench,
    thruster_directions,
    thruster_positions,
)


def _wrench_from_forces(thrusts, alpha, beta, l, d):
    """tau = sum_i (F_i, r_i x F_i), with F_i = f_i times the unit direction."""
    forces = np.asarray(thrusts)[:, None] * thruster_directions(alpha, beta)
    moments = np.cross(thruster_positions(l, d), forces)
    return np.concatenate([forces.sum(axis=0), moments.sum(axis=0)])


@pytest.mark.parametrize('seed', range(5))
def test_eq4_equals_sum_of_thruster_forces_and_moments(seed: int) -> None:
    rng = np.random.default_rng(seed)
    for _ in range(200):
        l, d = rng.uniform(0.1, 2.0, size=2)
        f = rng.uniform(-40.0, 40.0, size=4)
        alpha, beta = rng.uniform(-np.pi, np.pi, size=2)
        np.testing.assert_allclose(thrust_wrench(f, alpha, beta, l, d),
                                   _wrench_from_forces(f, alpha, beta, l, d),
                                   rtol=1e-12, atol=1e-12)


def test_eq4_printed_rows() -> None:
    """Row by row as printed in the paper, for one asymmetric input."""
    l, d = 0.6, 0.4
    f1, f2, f3, f4 = 3.0, -5.0, 7.0, 11.0
    a, b = 0.3, -1.1
    ca, sa, cb, sb = np.cos(a), np.sin(a), np.cos(b), np.sin(b)
    r2 = np.sqrt(2.0)
    expected = [
        (f1 * ca + f2 * ca + f3 * cb + f4 * cb) / r2,
        (f1 * ca - f2 * ca + f3 * cb - f4 * cb) / r2,
        -f1 * sa - f2 * sa - f3 * sb - f4 * sb,
        d / 2 * (f1 * sa - f2 * sa - f3 * sb + f4 * sb),
        l / 2 * (f1 * sa + f2 * sa - f3 * sb - f4 * sb),
        (l + d) / (2 * r2) * (f1 * ca - f2 * ca - f3 * cb + f4 * cb),
    ]
    np.testing.assert_allclose(thrust_wrench([f1, f2, f3, f4], a, b, l, d), expected,
                               rtol=1e-14)


def test_positive_thrust_at_plus_90_deg_points_up() -> None:
    tau = thrust_wrench([1.0, 1.0, 1.0, 1.0], np.pi / 2, np.pi / 2, 0.6, 0.4)
    np.testing.assert_allclose(tau, [0, 0, -4.0, 0, 0, 0], atol=1e-15)


def test_linear_form_eq5_and_batch_shapes() -> None:
    rng = np.random.default_rng(7)
    f = rng.uniform(-40, 40, size=(50, 4))
    alpha = rng.uniform(-1.5, 1.5, size=50)
    beta = rng.uniform(-1.5, 1.5, size=50)
    A = allocation_matrix(0.6, 0.4)
    assert A.shape == (6, 8)
    assert np.linalg.matrix_rank(A) == 6
    batch = thrust_wrench(f, alpha, beta, 0.6, 0.4)
    assert batch.shape == (50, 6)
    for i in range(50):
        np.testing.assert_allclose(A @ q_vector(f[i], alpha[i], beta[i]), batch[i], atol=1e-12)
