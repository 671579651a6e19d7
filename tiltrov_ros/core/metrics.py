"""``metrics.json`` from a :class:`~tiltrov_ros.core.runlog.RunLog`: the one implementation.

``tiltrov sim`` (a RunLog from the headless runner) and ``tiltrov analyze`` (a
RunLog read from a bag) both call :func:`compute_metrics`, so the same run gives
the same numbers. numpy only; units SI (m, rad, s, N).

Errors (:func:`control_errors`)
    On the control grid: at each tick ``tc`` the pose is the odometry sample
    stamped ``tc`` (the plant row with ``t == tc``, to :data:`STAMP_TOLERANCE`;
    ticks without one are dropped and counted in ``unmatched_ticks``), and
    ``e = eta_d - eta`` with eta_d from the setpoint in force at the tick, ZYX
    Euler angles of both quaternions, angle errors wrapped to (-pi, pi]. This is
    the error the controller saw.

The interface's keys (docs/simulation.md)
    ``rms_error[dof]``: sqrt(mean(e^2)) over all ticks.
    ``final_error[dof]``: mean |e| over the ticks of the last
    :data:`FINAL_WINDOW` (10 s) of the run, the run ending at the last plant
    sample.
    ``max_tilt_rate[front|rear]``: max |actual tilt velocity| over the plant
    grid (the servo's backward difference, as ``joint_states`` carries it),
    rad/s.
    ``thrust_saturation_fraction``: fraction of ticks at which any
    |thrust_cmd| >= max_thrust (relative tolerance :data:`SATURATION_RTOL`);
    max_thrust from ``meta['max_thrust']``.
    ``wrench_error_rms``: sqrt(mean(||wrench_cmd - wrench_achieved||^2)) over
    ticks, N-and-N m mixed as the allocator's wrench is.

Further keys
    ``max_error[dof]``: max |e|.
    ``settling_time[dof]``: the time (s, run clock) of the first tick from
    which |e| stays within the DOF's band until the end of the run; the first
    tick's time if it never leaves it; ``null`` (not settled) if that last stay
    in the band is shorter than :data:`SETTLING_HOLD` (5 s), so an oscillation
    that happens to be inside the band at the end does not count. The
    band (``settling_band[dof]``) is the larger of :data:`SETTLING_FRACTION`
    (2 %) of the reference's span over the run (max - min of eta_d, angles
    unwrapped) and an
    absolute floor, :data:`SETTLING_FLOOR` (10 mm, 0.5 deg), so a DOF held at
    0 still has a band.
    ``oscillation_std[dof]``, ``oscillation_peak_to_peak[dof]``: population
    standard deviation and max - min of e over the last
    :data:`OSCILLATION_WINDOW` (20 s): a converged run has ~0, a limit cycle
    does not (a constant offset does not count).
    ``servo_travel[front|rear]``: sum of |tilt_i+1 - tilt_i| over the plant
    grid, rad: how far each servo moved.
    ``saturation_duty[thruster_1..4]``: per thruster, the fraction of ticks
    with its command at the limit.
    ``thrust_energy_proxy``: integral of sum_i |f_i|^1.5 dt over the plant
    grid (actual thrusts, held over each step), N^1.5 s. By momentum theory a
    propeller's ideal power is T^1.5 / sqrt(2 rho A), so this is proportional
    to the propulsion energy for equal thrusters.
    ``infeasible_fraction``: fraction of ticks whose achieved wrench misses
    the command by more than the allocator's own test,
    ||achieved - cmd|| > FEASIBILITY_RTOL * max(||cmd||, max_thrust).
    ``ticks``, ``unmatched_ticks``, ``duration`` (s), and ``run`` (scenario,
    controller, allocator_mode and backend, from the meta) describe what was
    measured.

The steady wrench (:mod:`tiltrov_ros.core.steady`)
    At the final setpoint (the last tick's, when its velocity is zero) and the
    run's mean current, true center of mass and lasting external wrench (the
    meta's ``robot``, ``disturbances`` and ``allocator_weights``):
    ``steady_wrench[X..N]`` the wrench that holds it (N, N m),
    ``steady_shortfall[X..N]`` what the best configuration within the servo
    range misses of it, ``steady_shortfall_ratio`` the largest shortfall in
    units of the wrench tolerance (at most 1: attainable) and
    ``steady_shortfall_ratio_full_circle`` the same with servos turning all
    the way round. ``None`` without those metas or a moving final setpoint.

Holding (:mod:`tiltrov_ros.core.hold`)
    ``hold``: ``{criterion, holds, verdict, reach}`` for a pd or pid run whose
    final setpoint stands still and which has no thruster fault, else ``None``:
    the hold criterion's name (the shipped station-keeping one, or a
    campaign's), whether the run meets its bounds, the verdict (``held``,
    ``physics``, ``servo_range``, ``control``) and the wander oracle's answer
    where the verdict needed it (:mod:`tiltrov_ros.core.wander`; else None).

A quantity that cannot be computed (no ticks, no max_thrust in the meta) is
``None`` (``null`` in JSON), never NaN.
"""

from __future__ import annotations

from dataclasses import dataclass
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tiltrov_ros.core.allocation import infeasible_rows
from tiltrov_ros.core.bounds import Bound
from tiltrov_ros.core.hold import HoldCriterion, judge
from tiltrov_ros.core.kinematics import euler_from_quat_rows, ssa
from tiltrov_ros.core.names import DOF_NAMES, SERVOS, THRUSTERS, WRENCH_DOFS
from tiltrov_ros.core.runlog import RunLog
from tiltrov_ros.core.steady import SteadyVerdict, from_meta

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: s, the window of ``final_error`` (the interface's: the last 10 s).
FINAL_WINDOW = 10.0
#: s, the window of the oscillation measures.
OSCILLATION_WINDOW = 20.0
#: fraction of the reference's span that defines the settling band.
SETTLING_FRACTION = 0.02
#: absolute floor of the settling band per DOF: 10 mm, 0.5 deg.
SETTLING_FLOOR: tuple[float, ...] = (0.01,) * 3 + (math.radians(0.5),) * 3
#: s, how long |e| must have stayed in the band at the end of the run to count as settled.
SETTLING_HOLD = 5.0
#: relative tolerance of "|thrust_cmd| >= max_thrust".
SATURATION_RTOL = 1e-9
#: s, a plant sample and a control tick with stamps this close are the same instant.
STAMP_TOLERANCE = 1e-6
#: s, slack on window edges (stamps are ns; float seconds round).
_EDGE = 1e-9



@dataclass(frozen=True)
class ControlErrors:
    """The pose and its error on the control grid (see the module docstring).

    t : (n,) tick times [s]
    eta_d, eta : (n, 6) desired and actual (x y z [m], roll pitch yaw [rad])
    e : (n, 6) eta_d - eta, angles wrapped to (-pi, pi]
    ticks : (n,) indices of these ticks in the RunLog's control grid
    rows : (n,) indices of their odometry samples in the plant grid
    """

    t: FloatArray
    eta_d: FloatArray
    eta: FloatArray
    e: FloatArray
    ticks: NDArray[np.intp]
    rows: NDArray[np.intp]


def _euler_rows(quaternions: FloatArray) -> FloatArray:
    if len(quaternions) == 0:
        return np.zeros((0, 3))
    return euler_from_quat_rows(quaternions)


def match_ticks(log: RunLog) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """(tick indices, plant row indices) of the ticks that have an odometry sample.

    The plant row of tick k is the one with |t - tc[k]| <= STAMP_TOLERANCE.
    """
    if len(log.t) == 0 or len(log.tc) == 0:
        empty = np.zeros(0, dtype=np.intp)
        return empty, empty
    order = np.argsort(log.t, kind='stable')
    ts = log.t[order]
    pos = np.clip(np.searchsorted(ts, log.tc), 0, len(ts) - 1)
    before = np.clip(pos - 1, 0, len(ts) - 1)
    nearer = np.where(np.abs(ts[before] - log.tc) < np.abs(ts[pos] - log.tc), before, pos)
    ok = np.abs(ts[nearer] - log.tc) <= STAMP_TOLERANCE
    return np.flatnonzero(ok).astype(np.intp), order[nearer[ok]].astype(np.intp)


def control_errors(log: RunLog) -> ControlErrors:
    """eta_d, eta and e = eta_d - eta at each control tick (angles wrapped)."""
    ticks, rows = match_ticks(log)
    eta = np.hstack([log.position[rows], _euler_rows(log.quaternion[rows])])
    eta_d = np.hstack([log.setpoint_position[ticks],
                       _euler_rows(log.setpoint_quaternion[ticks])])
    e = eta_d - eta
    e[:, 3:] = ssa(e[:, 3:])
    return ControlErrors(log.tc[ticks], eta_d, eta, e, ticks, rows)


def run_end(log: RunLog) -> float:
    """s, the end of the run: its last plant sample (or last tick, without samples)."""
    if len(log.t):
        return float(np.max(log.t))
    return float(np.max(log.tc)) if len(log.tc) else 0.0


def _per(names: tuple[str, ...], values: FloatArray | None) -> dict[str, float | None]:
    if values is None:
        return dict.fromkeys(names)
    return {name: _num(v) for name, v in zip(names, values)}


def _num(value: Any) -> float | None:
    v = float(value)
    return v if math.isfinite(v) else None


def _window(t: FloatArray, end: float, width: float) -> BoolArray:
    mask: BoolArray = t >= end - width - _EDGE
    return mask


def settling_times(err: ControlErrors) -> tuple[list[float | None], FloatArray]:
    """Settling time per DOF (s, None if not settled) and the bands used."""
    if len(err.t) == 0:
        return [None] * 6, np.array(SETTLING_FLOOR)
    # Angles unwrapped along time, so a yaw reference through +-180 deg has its true span.
    span = np.ptp(np.hstack([err.eta_d[:, :3], np.unwrap(err.eta_d[:, 3:], axis=0)]), axis=0)
    band = np.maximum(SETTLING_FRACTION * span, np.array(SETTLING_FLOOR))
    out: list[float | None] = []
    for k in range(6):
        outside = np.flatnonzero(np.abs(err.e[:, k]) > band[k])
        if len(outside) == 0:
            out.append(float(err.t[0]))
        elif (outside[-1] == len(err.t) - 1
              or float(np.max(err.t)) - float(err.t[outside[-1] + 1]) < SETTLING_HOLD - _EDGE):
            out.append(None)
        else:
            out.append(float(err.t[outside[-1] + 1]))
    return out, band


def final_setpoint(log: RunLog) -> FloatArray | None:
    """The last tick's setpoint attitude (w, x, y, z) when it stands still, else None."""
    if not len(log.tc) or np.any(log.setpoint_velocity[-1] != 0.0):
        return None
    out: FloatArray = log.setpoint_quaternion[-1]
    return out


def _steady(log: RunLog) -> SteadyVerdict | None:
    """The oracle at the last tick's setpoint, when it stands still (module docstring)."""
    quaternion = final_setpoint(log)
    return None if quaternion is None else from_meta(log.meta, quaternion)


def compute_metrics(log: RunLog, *, max_thrust: float | None = None,
                    criterion: HoldCriterion | None = None,
                    bounds: tuple[Bound, ...] | None = None) -> dict[str, Any]:
    """Every metric of the module docstring, as a JSON-ready dict.

    Parameters
    ----------
    log : RunLog
        One run (runner or bag).
    max_thrust : float, optional
        Thrust limit [N]; default ``log.meta['max_thrust']``. Without either, the
        saturation and feasibility keys are None.
    criterion : HoldCriterion, optional
        What ``hold`` judges the run by (default: the shipped station-keeping
        criterion, :func:`tiltrov_ros.core.hold.shipped`); ``bounds``: those of its
        bounds that apply to the run, when the caller knows (a campaign's).

    Returns
    -------
    dict
        The interface's keys first, then the further keys.
    """
    limit = max_thrust if max_thrust is not None else log.meta.get('max_thrust')
    limit = float(limit) if isinstance(limit, (int, float)) and limit > 0 else None
    err = control_errors(log)
    n = len(err.t)
    end = run_end(log)
    metrics: dict[str, Any] = {}

    if n:
        e = err.e
        abs_e = np.abs(e)
        final = _window(err.t, end, FINAL_WINDOW)
        osc = _window(err.t, end, OSCILLATION_WINDOW)
        metrics['rms_error'] = _per(DOF_NAMES, np.sqrt(np.mean(e**2, axis=0)))
        metrics['final_error'] = _per(DOF_NAMES, np.mean(abs_e[final], axis=0))
    else:
        metrics['rms_error'] = _per(DOF_NAMES, None)
        metrics['final_error'] = _per(DOF_NAMES, None)

    if len(log.t):
        rate = np.max(np.abs(log.tilt_velocity), axis=0)
        travel = np.sum(np.abs(np.diff(log.tilt_position, axis=0)), axis=0)
        dt = np.diff(log.t)
        power = np.sum(np.abs(log.thrust[:-1]) ** 1.5, axis=1)
        energy: float | None = float(np.sum(power * dt))
    else:
        rate = travel = None
        energy = None
    metrics['max_tilt_rate'] = _per(SERVOS, rate)

    ticks = len(log.tc)
    if ticks and limit is not None:
        at_limit = np.abs(log.thrust_cmd) >= limit * (1.0 - SATURATION_RTOL)
        metrics['thrust_saturation_fraction'] = float(np.mean(np.any(at_limit, axis=1)))
        duty: FloatArray | None = np.mean(at_limit, axis=0)
        infeasible: float | None = float(np.mean(
            infeasible_rows(log.wrench_cmd, log.wrench_achieved, limit)))
    else:
        metrics['thrust_saturation_fraction'] = None
        duty = None
        infeasible = None
    if ticks:
        diff = log.wrench_cmd - log.wrench_achieved
        metrics['wrench_error_rms'] = float(np.sqrt(np.mean(np.sum(diff**2, axis=1))))
    else:
        metrics['wrench_error_rms'] = None

    # ---- beyond the interface's keys
    if n:
        settle, band = settling_times(err)
        metrics['max_error'] = _per(DOF_NAMES, np.max(abs_e, axis=0))
        metrics['settling_time'] = dict(zip(DOF_NAMES, settle))
        metrics['settling_band'] = _per(DOF_NAMES, band)
        metrics['oscillation_std'] = _per(DOF_NAMES, np.std(e[osc], axis=0))
        metrics['oscillation_peak_to_peak'] = _per(DOF_NAMES, np.ptp(e[osc], axis=0))
    else:
        for key in ('max_error', 'settling_time', 'settling_band', 'oscillation_std',
                    'oscillation_peak_to_peak'):
            metrics[key] = _per(DOF_NAMES, None)
    metrics['servo_travel'] = _per(SERVOS, travel)
    metrics['saturation_duty'] = _per(THRUSTERS, duty)
    metrics['thrust_energy_proxy'] = energy
    metrics['infeasible_fraction'] = infeasible
    verdict = _steady(log)
    metrics['steady_wrench'] = _per(WRENCH_DOFS, None if verdict is None else verdict.wrench)
    metrics['steady_shortfall'] = _per(
        WRENCH_DOFS, None if verdict is None else verdict.in_range.shortfall)
    metrics['steady_shortfall_ratio'] = None if verdict is None else _num(
        verdict.in_range.ratio)
    metrics['steady_shortfall_ratio_full_circle'] = None if verdict is None else _num(
        verdict.full_circle.ratio)
    metrics['hold'] = judge(metrics, log.meta, final_setpoint(log), criterion, bounds) \
        if n else None
    metrics['ticks'] = n
    metrics['unmatched_ticks'] = ticks - n
    metrics['duration'] = end
    metrics['run'] = {key: log.meta.get(key) for key in
                      ('scenario', 'controller', 'allocator_mode', 'backend')}
    return metrics


def write_metrics(metrics: dict[str, Any], path: str | Path) -> Path:
    """Write ``metrics`` as JSON (sorted as built, 2-space indent, no NaN)."""
    target = Path(path)
    target.write_text(json.dumps(metrics, indent=2, allow_nan=False) + '\n', encoding='utf-8')
    return target


def metric_differences(got: Any, expected: Any, *, rtol: float = 1e-9, atol: float = 1e-9,
                       path: str = 'metrics') -> list[str]:
    """Where two metrics dictionaries differ: one line per difference, empty when equal.

    Keys must match in order; counts, strings and nulls exactly; floats to
    ``rtol``/``atol`` (as :func:`math.isclose`). ``tiltrov demo`` checks a
    recorded run against the headless one with it, the tests likewise.
    """
    if type(got) is not type(expected):
        return [f'{path}: {type(got).__name__} {got!r} != {type(expected).__name__} '
                f'{expected!r}']
    if isinstance(expected, dict):
        if list(got) != list(expected):
            return [f'{path}: keys {list(got)} != {list(expected)}']
        return [line for key in expected
                for line in metric_differences(got[key], expected[key], rtol=rtol, atol=atol,
                                               path=f'{path}.{key}')]
    if isinstance(expected, float):
        if not math.isclose(got, expected, rel_tol=rtol, abs_tol=atol):
            return [f'{path}: {got!r} != {expected!r}']
        return []
    return [] if got == expected else [f'{path}: {got!r} != {expected!r}']
