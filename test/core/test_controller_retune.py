"""``retune``: run-time gain changes keep the controller's state."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from tiltrov_ros.core.controllers import (
    PDController,
    PIDController,
    Reference,
    SwitchingController,
    load_controller_config,
    make_controller,
    retune,
)
from tiltrov_ros.core.params import load_robot_params

ROBOT = load_robot_params()
Q0 = np.array([1.0, 0.0, 0.0, 0.0])
REF = Reference(np.array([0.5, -0.2, 0.3]), Q0, np.zeros(6))


def _drive(controller, steps: int = 10) -> None:
    for k in range(steps):
        controller.update(0.05 * k, np.zeros(3), Q0, np.zeros(6), REF)


def test_pid_keeps_its_integral_clamped_to_the_new_limit() -> None:
    config = load_controller_config().with_kind('pid')
    old = make_controller(config, ROBOT)
    _drive(old)
    assert isinstance(old, PIDController) and np.any(old.integral != 0.0)
    smaller = replace(config, gains=replace(config.gains, integral_limit=(0.01,) * 6))
    new = retune(old, smaller, ROBOT)
    assert isinstance(new, PIDController) and new is not old
    bound = 0.01 / np.array(config.gains.ki)
    np.testing.assert_allclose(new.integral, np.clip(old.integral, -bound, bound))
    assert new._last_t == old._last_t
    assert new.gains.integral_limit == (0.01,) * 6


def test_switching_keeps_its_mode_and_timers() -> None:
    config = load_controller_config().with_kind('switching')
    old = make_controller(config, ROBOT)
    _drive(old)
    assert isinstance(old, SwitchingController) and old.mode is not None
    stiffer = replace(config, gains=replace(config.gains, kp=tuple(2 * k for k in
                                                                  config.gains.kp)))
    new = retune(old, stiffer, ROBOT)
    assert isinstance(new, SwitchingController)
    assert (new.mode, new.tilts, new.switches) == (old.mode, old.tilts, old.switches)
    assert (new._switched_at, new._moving_until) == (old._switched_at, old._moving_until)
    out_new = new.update(0.5, np.zeros(3), Q0, np.zeros(6), REF)
    out_old = old.update(0.5, np.zeros(3), Q0, np.zeros(6), REF)
    np.testing.assert_allclose(out_new.wrench, 2 * out_old.wrench)


def test_another_kind_starts_afresh() -> None:
    config = load_controller_config()
    old = make_controller(config.with_kind('pid'), ROBOT)
    _drive(old)
    new = retune(old, config.with_kind('pd'), ROBOT)
    assert isinstance(new, PDController)
