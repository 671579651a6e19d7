"""Disturbances: center-of-mass error, Gauss-Markov current (exact, seeded), external wrench."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tiltrov_ros.core.disturbances import (
    PAPER_COM_ERROR,
    Disturbances,
    ExternalWrench,
    OceanCurrent,
)
from tiltrov_ros.core.errors import ParameterError
from tiltrov_ros.core.params import load_robot_params


def test_true_params_add_the_com_error_to_the_nominal_cg() -> None:
    nominal = load_robot_params()
    true = Disturbances(com_error=PAPER_COM_ERROR).true_params(nominal)
    np.testing.assert_allclose(true.center_of_gravity, [0.01, 0.0, 0.025], atol=1e-15)
    assert nominal.center_of_gravity == (0.0, 0.0, 0.02)
    assert true.mass_matrix == nominal.mass_matrix


@pytest.mark.parametrize(('name', 'kwargs'), [
    ('com_error', {'com_error': (0.01, 0.0)}),
    ('current', {'current': (0.1, math.nan, 0.0)}),
    ('current_std', {'current_std': (0.1, -0.1, 0.0)}),
    ('current_time_constant', {'current_time_constant': (10.0, 0.0, 10.0)}),
    ('seed', {'seed': -1}),
    ('seed', {'seed': True}),
    ('seed', {'seed': 1.5}),
    ('external_wrench', {'external_wrench': (1.0, 2.0, 3.0)}),
])
def test_invalid_disturbances_name_the_parameter(name: str, kwargs: dict) -> None:
    with pytest.raises(ParameterError) as info:
        Disturbances(**kwargs)
    assert info.value.name == name
    assert 'allowed' in str(info.value)


def test_constant_current_never_changes() -> None:
    current = OceanCurrent(mean=(0.3, -0.1, 0.05))
    for _ in range(100):
        current.advance(0.01)
        assert current.velocity == (0.3, -0.1, 0.05)


def _run(seed: int, n: int = 500, h: float = 0.01) -> np.ndarray:
    d = Disturbances(current=(0.2, 0.0, 0.0), current_std=(0.1, 0.05, 0.0),
                     current_time_constant=(2.0, 5.0, 1.0), seed=seed)
    current = OceanCurrent.from_disturbances(d)
    out = [current.velocity]
    for _ in range(n):
        current.advance(h)
        out.append(current.velocity)
    return np.array(out)


def test_gauss_markov_is_deterministic_for_a_seed() -> None:
    a, b, c = _run(3), _run(3), _run(4)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    np.testing.assert_array_equal(a[0], [0.2, 0.0, 0.0])   # starts at the mean
    np.testing.assert_array_equal(a[:, 2], 0.0)            # sigma 0: that axis stays constant
    assert np.std(a[:, 0]) > 0.0


@pytest.mark.parametrize('h', [0.1, 0.5, 1.0])
def test_gauss_markov_variance_is_exact_for_any_step(h: float) -> None:
    """Ensemble variance at t = 2 s from b(0) = 0 is sigma^2 (1 - exp(-2 t / T_c)),
    whatever the step: the discretisation is exact, not Euler."""
    sigma, tc, t_end = 0.2, 1.5, 2.0
    steps = round(t_end / h)
    rng = np.random.default_rng(11)
    finals = []
    for _ in range(3000):
        current = OceanCurrent(std=(sigma, sigma, sigma), time_constant=(tc, tc, tc), rng=rng)
        for _ in range(steps):
            current.advance(h)
        finals.append(current.gauss_markov)
    var = np.var(np.array(finals), axis=0)
    expected = sigma ** 2 * (1.0 - math.exp(-2.0 * t_end / tc))
    # 9000 samples: the variance estimate's relative standard error is about 1.5 %.
    np.testing.assert_allclose(var, expected, rtol=0.06)


def test_gauss_markov_stationary_std_and_correlation() -> None:
    sigma, tc, h = 0.1, 1.0, 0.1
    current = OceanCurrent(std=(sigma, 0.0, 0.0), time_constant=(tc, 1.0, 1.0),
                           rng=np.random.default_rng(5))
    for _ in range(200):       # forget b(0) = 0
        current.advance(h)
    samples = []
    for _ in range(40000):
        current.advance(h)
        samples.append(current.gauss_markov[0])
    b = np.array(samples)
    assert np.std(b) == pytest.approx(sigma, rel=0.05)
    lag1 = np.corrcoef(b[:-1], b[1:])[0, 1]
    assert lag1 == pytest.approx(math.exp(-h / tc), abs=0.01)


def test_external_wrench_constant_or_callable() -> None:
    const = ExternalWrench((1.0, 2.0, 3.0, 4.0, 5.0, 6.0))
    assert const.is_constant and const(12.3) == (1.0, 2.0, 3.0, 4.0, 5.0, 6.0)
    ramp = ExternalWrench(lambda t: [t, 0.0, 0.0, 0.0, 2.0 * t, 0.0])
    assert not ramp.is_constant
    assert ramp(1.5) == (1.5, 0.0, 0.0, 0.0, 3.0, 0.0)
    with pytest.raises(ValueError, match='6 finite'):
        ExternalWrench(lambda t: [math.nan] * 6)(0.0)
    with pytest.raises(ValueError, match='6 finite'):
        ExternalWrench(lambda t: [1.0, 2.0])(0.0)
    with pytest.raises(ParameterError):
        ExternalWrench((1.0, 2.0))


def test_describe_is_json_serialisable() -> None:
    import json
    d = Disturbances(com_error=PAPER_COM_ERROR, external_wrench=lambda t: [0.0] * 6)
    text = json.dumps(d.describe())
    assert '"seed": 0' in text
