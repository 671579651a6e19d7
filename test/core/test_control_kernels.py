"""The compiled control laws against the numpy reference (``controller.compiled`` False):
the tracking error of eq. (16) (Euler angles, ssa, J(eta) with its gimbal guard), PD,
PID (g_hat, clamped integral) and the switching arithmetic, on seeded random states."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tiltrov_ros.core import control_kernels as ck
from tiltrov_ros.core import jit
from tiltrov_ros.core.controllers import (
    Gains,
    PDController,
    PIDController,
    Reference,
    SwitchingController,
    SwitchingSettings,
    load_controller_config,
    make_controller,
    tracking_error,
)
from tiltrov_ros.core.kinematics import quat_from_euler, ssa
from tiltrov_ros.core.params import load_robot_params

#: The comparisons need the kernels compiled; the API checks run on either backend.
needs_kernels = pytest.mark.skipif(not jit.compiled(), reason='the numpy backend has no kernels')

ROBOT = load_robot_params()
RTOL = 1e-12


def _state(rng: np.random.Generator, near_lock: bool = False
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, Reference]:
    """Random odometry and setpoint: any attitude, angle errors across +-pi (ssa),
    non-unit quaternions; ``near_lock``: pitch within a hair of +-90 deg (the gimbal
    guard of J)."""
    euler = rng.uniform(-math.pi, math.pi, 3)
    euler[1] = rng.uniform(-1.55, 1.55)
    kind = rng.integers(4)
    if near_lock:
        euler[1] = math.copysign(math.pi / 2 - 10.0 ** rng.uniform(-8, -5.7), rng.normal())
    euler_d = euler + rng.normal(scale=0.5, size=3)
    if kind == 1:
        euler_d[2] = euler[2] + math.pi + rng.normal(scale=1e-3)
    q = quat_from_euler(*euler) * rng.uniform(0.5, 2.0)
    q_d = quat_from_euler(*euler_d) * rng.uniform(0.5, 2.0)
    reference = Reference(rng.normal(size=3), q_d, rng.normal(scale=0.2, size=6))
    return rng.normal(size=3), q, rng.normal(scale=[0.5, 0.5, 0.5, 1.0, 1.0, 1.0]), reference


def _close(a: np.ndarray, b: np.ndarray, rtol: float = RTOL) -> None:
    np.testing.assert_allclose(a, b, rtol=rtol, atol=rtol * max(1.0, float(np.max(np.abs(b)))))


@needs_kernels
@pytest.mark.parametrize(('seed', 'near_lock'), [(0, False), (1, False), (2, False),
                                                 (3, True), (4, True)])
def test_tracking_error_equals_the_reference(seed: int, near_lock: bool) -> None:
    """To 1e-12 (angles modulo 2 pi). Within 2e-6 rad of pitch +-90 deg roll and yaw
    come from atan2 of entries of R of the size of cos(pitch) (and J, past its guard,
    holds them over cos(pitch)), so any two implementations' rounding differs there
    by up to some eps / cos(pitch): the tolerance is 1e-14 / cos(pitch), at most 1e-6."""
    rng = np.random.default_rng(seed)
    work = np.zeros(ck.WORK_SIZE)
    for _ in range(200):
        position, q, nu, ref = _state(rng, near_lock)
        assert ck.tracking(position, q, nu, ref.position, ref.quaternion, ref.velocity,
                           work) == 0
        err = tracking_error(position, q, nu, ref)
        rtol = max(RTOL, 1e-14 / abs(math.cos(err.eta[4])))
        eta = work[ck.WORK_ETA:ck.WORK_ETA + 6]
        _close(eta[:5], err.eta[:5], rtol)
        _close(np.array(ssa(eta[5] - err.eta[5])), np.array(0.0), rtol)
        _close(work[ck.WORK_E:ck.WORK_E + 3], err.e[:3])
        _close(np.array([ssa(a - b) for a, b in zip(work[ck.WORK_E + 3:ck.WORK_E + 6],
                                                    err.e[3:])]), np.zeros(3), rtol)
        assert near_lock == (abs(math.cos(err.eta[4])) < 3e-6)
        _close(work[ck.WORK_J:ck.WORK_J + 36].reshape(6, 6), err.J, rtol)
        _close(work[ck.WORK_E_DOT:ck.WORK_E_DOT + 6], err.e_dot, rtol)


def _pair(kind: str, seed: int) -> tuple[object, object]:
    rng = np.random.default_rng(100 + seed)
    gains = Gains(tuple(rng.uniform(1, 500, 6)), tuple(rng.uniform(1, 200, 6)),
                  tuple(rng.uniform(0, 50, 6) * (rng.uniform(size=6) < 0.8)),
                  tuple(rng.uniform(0.5, 20, 6)), antiwindup=float(rng.choice([0.0, 1.0, 3.0])))
    settings = SwitchingSettings(hysteresis=0.3, dwell_time=0.2, settle_time=0.05)
    build = {'pd': lambda: PDController(gains), 'pid': lambda: PIDController(gains, ROBOT),
             'switching': lambda: SwitchingController(gains, settings, ROBOT)}[kind]
    compiled, reference = build(), build()
    reference.compiled = False       # type: ignore[attr-defined]
    assert compiled.compiled         # type: ignore[attr-defined]
    return compiled, reference


@needs_kernels
@pytest.mark.parametrize('kind', ['pd', 'pid', 'switching'])
@pytest.mark.parametrize('seed', range(4))
def test_each_law_equals_the_reference_over_a_run_of_updates(kind: str, seed: int) -> None:
    """With the achieved wrench of the previous command given at most updates: short
    of it by nothing, by a little (within the tolerance) or by a lot in some DOFs."""
    compiled, reference = _pair(kind, seed)
    rng = np.random.default_rng(seed)
    t = 0.0
    last = None
    frozen = 0
    for _ in range(300):
        t += float(rng.choice([0.05, 0.05, 0.0, 0.7, 1.5, -0.1]))
        position, q, nu, ref = _state(rng)
        if rng.uniform() < 0.3:          # near the setpoint: small errors, no saturation
            position, q = ref.position + rng.normal(scale=0.01, size=3), ref.quaternion
        achieved = None
        if last is not None and rng.uniform() < 0.8:
            short = rng.choice([0.0, 0.01, 5.0], size=6) * rng.normal(size=6)
            achieved = last - short
        before = getattr(reference, 'integral', np.zeros(6)).copy()
        a = compiled.update(t, position, q, nu, ref, achieved=achieved)  # type: ignore[attr-defined]
        b = reference.update(t, position, q, nu, ref, achieved=achieved)  # type: ignore[attr-defined]
        last = b.wrench
        _close(a.wrench, b.wrench)
        if kind == 'pid' and achieved is not None and reference.uses_achieved:  # type: ignore[attr-defined]
            frozen += int(np.sum(reference.integral == before))  # type: ignore[attr-defined]
        assert (a.mode, a.tilt_request) == (b.mode, b.tilt_request)
        if kind == 'pid':
            _close(compiled.integral, reference.integral)   # type: ignore[attr-defined]
            assert compiled._last_t == reference._last_t    # type: ignore[attr-defined]
    antiwindup = getattr(reference, 'uses_achieved', False)
    assert not antiwindup or frozen > 20          # the anti-windup held some DOFs still


def test_the_shipped_controllers_accept_sequences_and_refuse_bad_input() -> None:
    config = load_controller_config()
    for kind in ('pd', 'pid', 'switching'):
        ctrl = make_controller(config.with_kind(kind), ROBOT)
        ref = Reference([0.0, 0.0, 1.0], [1.0, 0.0, 0.0, 0.0], [0.0] * 6)  # type: ignore[arg-type]
        out = ctrl.update(0.0, [0.0, 0.0, 0.0], (1.0, 0.0, 0.0, 0.0), [0.0] * 6, ref)  # type: ignore[arg-type]
        assert np.all(np.isfinite(out.wrench)) and out.wrench.shape == (6,)
        with pytest.raises(ValueError, match='not a valid quaternion'):
            ctrl.update(0.05, np.zeros(3), np.zeros(4), np.zeros(6), ref)
        with pytest.raises(ValueError, match='not a valid quaternion'):
            ctrl.update(0.05, np.zeros(3), np.array([math.nan, 0, 0, 1.0]), np.zeros(6), ref)
        with pytest.raises(ValueError):     # the kernels' message names nu; numpy's not
            ctrl.update(0.05, np.zeros(3), np.array([1.0, 0, 0, 0]), np.zeros(5), ref)


def test_a_refused_update_leaves_the_pid_as_it_was() -> None:
    ctrl = make_controller(load_controller_config().with_kind('pid'), ROBOT)
    assert isinstance(ctrl, PIDController)
    ref = Reference(np.array([1.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(6))
    ctrl.update(0.0, np.zeros(3), ref.quaternion, np.zeros(6), ref)
    ctrl.update(0.05, np.zeros(3), ref.quaternion, np.zeros(6), ref)
    integral, last = ctrl.integral.copy(), ctrl._last_t
    with pytest.raises(ValueError):
        ctrl.update(0.1, np.zeros(3), np.zeros(4), np.zeros(6), ref)
    np.testing.assert_array_equal(ctrl.integral, integral)
    assert ctrl._last_t == last and np.any(integral != 0.0)
