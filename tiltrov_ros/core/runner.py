"""The headless closed loop: plant at 10 ms, controller and allocator at 50 ms (ZOH).

This is the paper's set-up (Section 4: sampling time 10 ms, control cycle
50 ms) and exactly what the ROS stack does in lockstep (ARCHITECTURE.md, "Time
and stamps" and "Controller interface"), without messages:

* plant step i is at t_i = i h (integer ns); control ticks are the steps with
  t_i a multiple of the control period T (a multiple of h);
* at a tick, with the plant state stamped t_i (after the step that ended at
  t_i)::

      reference = reference_fn(t_i)     # (position (3), quaternion (4), velocity (6))
      out = controller.update(t_i, position, quaternion, nu, reference,
                              achieved=prev_res.achieved)   # None at the first tick
      if out.tilt_request is None:
          res = allocator.allocate(out.wrench, previous=prev_res)
      else:
          res = allocator.allocate_fixed(out.wrench, tilt_front, tilt_rear, previous=prev_res)
      plant.command(res.thrusts, (res.tilt_front, res.tilt_rear))   # held until the next tick

  then the plant steps. t_i is passed as float seconds, ``seconds(t_ns)``, as
  the nodes do; ``achieved`` is the wrench the allocator achieved at the previous
  tick (the node's ``wrench_achieved`` stamped t_i - T);
* the :class:`~tiltrov_ros.core.runlog.RunLog` gets one plant row per step
  including t = 0 (N + 1 rows for N steps) and one control row per tick, ticks
  at t_i < duration (the commands of a row are in force over [t_i, t_i + T)).

The controller and allocator are anything with the methods of
:class:`ControllerLike` and :class:`AllocatorLike` (``core/controllers.py`` and
``core/allocation.py``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass
import math
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tiltrov_ros.core import jit
from tiltrov_ros.core.allocation import (
    AllocatorConfig,
    ThrustAllocator,
    load_allocator_config,
)
from tiltrov_ros.core.controllers import (
    Controller,
    ControllerConfig,
    Reference,
    load_controller_config,
    make_controller,
)
from tiltrov_ros.core.errors import ParameterError
from tiltrov_ros.core.kinematics import quat_from_euler
from tiltrov_ros.core.params import RobotParams, load_control_period, load_robot_params
from tiltrov_ros.core.plant import SAMPLE_COLUMNS, SAMPLE_WIDTH, Plant
from tiltrov_ros.core.runlog import RunLog
from tiltrov_ros.core.scenarios import Scenario, ThrusterFault, failed_at, load_scenario
from tiltrov_ros.core.timebase import seconds, to_ns

FloatArray = NDArray[np.float64]

#: The paper's control cycle (Section 4), ns.
DEFAULT_CONTROL_PERIOD_NS = 50_000_000


ReferenceFn = Callable[[float], tuple[ArrayLike, ArrayLike, ArrayLike]]


class ControlOutputLike(Protocol):
    """What ``controller.update`` returns."""

    @property
    def wrench(self) -> ArrayLike:
        """(6,) body wrench (X Y Z K M N), N and N m."""

    @property
    def tilt_request(self) -> Any:
        """None, or (tilt_front, tilt_rear), rad, for fixed-tilt allocation."""


class ControllerLike(Protocol):
    def update(self, t: float, position: FloatArray, quaternion: FloatArray, nu: FloatArray,
               reference: Any, /, achieved: FloatArray | None = None) -> ControlOutputLike:
        """The wrench for the state at time t (s) and the reference at t; ``achieved``:
        what the allocator achieved of the previous wrench, passed only to a controller
        whose ``uses_achieved`` is true (the others are called without it)."""


class AllocationResultLike(Protocol):
    """What the allocator returns (``ThrustAllocator`` results)."""

    @property
    def thrusts(self) -> ArrayLike:
        """(4,) N."""

    @property
    def tilt_front(self) -> float:
        """alpha, rad."""

    @property
    def tilt_rear(self) -> float:
        """beta, rad."""

    @property
    def achieved(self) -> ArrayLike:
        """(6,) eq. (4) of thrusts and tilts."""

    @property
    def feasible(self) -> bool:
        """True when achieved == wrench."""


class AllocatorLike(Protocol):
    def allocate(self, wrench: FloatArray, /, previous: Any = None) -> AllocationResultLike:
        """Thrusts and tilts for a wrench."""

    def allocate_fixed(self, wrench: FloatArray, tilt_front: float, tilt_rear: float, /,
                       previous: Any = None) -> AllocationResultLike:
        """Thrusts for a wrench at given tilts."""


def _vector(value: ArrayLike, n: int, what: str) -> FloatArray:
    """A float copy of ``value`` (so a caller reusing its arrays cannot alter the log)."""
    arr = np.array(value, dtype=float)
    if arr.shape != (n,):
        raise ValueError(f'{what}: expected shape ({n},), got {arr.shape}')
    return arr


def run(plant: Plant, controller: ControllerLike, allocator: AllocatorLike,
        reference_fn: ReferenceFn, duration: float, *,
        control_period_ns: int = DEFAULT_CONTROL_PERIOD_NS,
        progress: Callable[[float], None] | None = None,
        meta: Mapping[str, Any] | None = None,
        faults: Sequence[ThrusterFault] = (),
        rebuild_allocator: Callable[[tuple[int, ...]], AllocatorLike] | None = None
        ) -> RunLog:
    """Run the closed loop for ``duration`` seconds from the plant's present state.

    Parameters
    ----------
    plant : Plant
        Stepped in place; its time must lie on the control grid (usually 0).
    controller, allocator
        See :class:`ControllerLike`, :class:`AllocatorLike`.
    reference_fn : callable
        t (s) -> (position (3), quaternion (w, x, y, z) (4), d(eta_d)/dt (6)).
    duration : float
        s; a whole number of plant steps.
    control_period_ns : int
        Control period T, ns; a whole number of plant steps (default 50 ms).
    progress : callable, optional
        Called with the fraction done (0 < f <= 1) about a hundred times, and
        with 1.0 at the end.
    meta : mapping, optional
        Added to the RunLog's meta (scenario, controller name, ...).
    faults : sequence of ThrusterFault, optional
        Thrusters failing during the run: the plant's at ``at``; at the first
        control tick from ``at + detected_after`` the allocator is replaced by
        ``rebuild_allocator(failed indices)`` (``previous`` kept), as a fault
        detector would tell the ``thrust_allocator`` node (``failed_thrusters``).

    Returns
    -------
    RunLog
    """
    h_ns = plant.step_ns
    duration_ns = to_ns(duration)
    if duration_ns <= 0 or duration_ns % h_ns:
        raise ParameterError('duration', f'got {duration!r} s; allowed: a positive whole '
                             f'number of plant steps ({seconds(h_ns)!r} s)')
    if (isinstance(control_period_ns, bool) or not isinstance(control_period_ns, int)
            or control_period_ns <= 0 or control_period_ns % h_ns):
        raise ParameterError('control_period_ns', f'got {control_period_ns!r}; allowed: a '
                             f'positive whole multiple of the plant step ({h_ns} ns)')
    if plant.time_ns % control_period_ns:
        raise ParameterError('plant.time_ns', f'got {plant.time_ns}; allowed: a multiple '
                             f'of the control period ({control_period_ns} ns)')
    n_steps = duration_ns // h_ns
    ticks_every = control_period_ns // h_ns
    report_every = max(1, n_steps // 100)

    # One sample row per plant step (t = 0 first): the plant writes them itself, n steps
    # per call (from one control tick to the next; step by step while faults may strike).
    samples = np.empty((n_steps + 1, SAMPLE_WIDTH))
    plant.write_sample(samples[0])
    rows: dict[str, list[Any]] = {name: [] for name in (
        'tc', 'setpoint_position', 'setpoint_quaternion', 'setpoint_velocity', 'wrench_cmd',
        'thrust_cmd', 'tilt_cmd', 'wrench_achieved')}
    infeasible = 0
    previous: Any = None
    known: tuple[int, ...] = ()
    i = 0
    next_report = report_every
    while i < n_steps:
        if faults:
            failed = failed_at(faults, seconds(plant.time_ns))
            if failed != plant.failed_thrusters:
                plant.set_failed_thrusters(failed)
        if i % ticks_every == 0:
            t = seconds(plant.time_ns)
            if faults and rebuild_allocator is not None:
                detected = failed_at(faults, t, detected=True)
                if detected != known:
                    known = detected
                    allocator = rebuild_allocator(known)
            p, q, v = reference_fn(t)
            reference = Reference(_vector(p, 3, 'reference position'),
                                  _vector(q, 4, 'reference quaternion'),
                                  _vector(v, 6, 'reference velocity'))
            # The achieved wrench only to a controller that reads it (the pid with its
            # anti-windup on): a controller of the plain protocol is called as ever.
            extra = ({'achieved': np.asarray(previous.achieved, dtype=float)}
                     if previous is not None and getattr(controller, 'uses_achieved', False)
                     else {})
            out = controller.update(t, plant.position, plant.quaternion, plant.nu, reference,
                                    **extra)
            wrench = _vector(out.wrench, 6, 'controller wrench')
            request = out.tilt_request
            if request is None:
                result = allocator.allocate(wrench, previous=previous)
            else:
                tilt_front, tilt_rear = request
                result = allocator.allocate_fixed(wrench, float(tilt_front), float(tilt_rear),
                                                  previous=previous)
            previous = result
            thrusts = _vector(result.thrusts, 4, 'allocated thrusts')
            tilts = (float(result.tilt_front), float(result.tilt_rear))
            plant.command(thrusts, tilts)
            infeasible += not result.feasible
            rows['tc'].append(t)
            rows['setpoint_position'].append(reference.position)
            rows['setpoint_quaternion'].append(reference.quaternion)
            rows['setpoint_velocity'].append(reference.velocity)
            rows['wrench_cmd'].append(wrench)
            rows['thrust_cmd'].append(thrusts)
            rows['tilt_cmd'].append(tilts)
            rows['wrench_achieved'].append(_vector(result.achieved, 6, 'achieved wrench'))
        k = 1 if faults else min(ticks_every - i % ticks_every, n_steps - i)
        plant.step(k, log=samples[i + 1:i + 1 + k])
        i += k
        if progress is not None and i >= next_report and i < n_steps:
            progress(i / n_steps)
            next_report = (i // report_every + 1) * report_every
    if progress is not None:
        progress(1.0)

    run_meta: dict[str, Any] = dict(plant.describe())
    run_meta.update(control_period=seconds(control_period_ns), duration=seconds(duration_ns),
                    infeasible_ticks=infeasible,
                    rejected_thrust_commands=plant.thrusters.rejected,
                    rejected_tilt_commands=plant.servos.rejected)
    if faults:
        run_meta['faults'] = [{'thruster': f.index + 1, 'at': f.at,
                               'detected_after': f.detected_after} for f in faults]
    run_meta.update(meta or {})
    return _runlog(samples, rows, run_meta)


def _runlog(samples: FloatArray, rows: dict[str, list[Any]], meta: dict[str, Any]) -> RunLog:
    arrays: dict[str, Any] = {name: np.ascontiguousarray(samples[:, SAMPLE_COLUMNS[field]])
                              for name, field in _PLANT_FIELDS.items()}
    for name, values in rows.items():
        arrays[name] = np.array(values, dtype=float)
    return RunLog(**arrays, meta=meta)


#: RunLog plant field -> the PlantSample field it logs.
_PLANT_FIELDS = {'t': 't', 'position': 'position', 'quaternion': 'quaternion', 'nu': 'nu',
                 'tilt_position': 'tilts', 'tilt_velocity': 'tilt_velocities',
                 'thrust': 'thrusts'}


def hold_reference(position: ArrayLike = (0.0, 0.0, 0.0),
                   quaternion: ArrayLike = (1.0, 0.0, 0.0, 0.0)) -> ReferenceFn:
    """A constant setpoint with zero feed-forward: ``reference_fn`` for station keeping."""
    p = _vector(position, 3, 'position')
    q = _vector(quaternion, 4, 'quaternion')
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(q))
            and math.isclose(float(np.linalg.norm(q)), 1.0, rel_tol=1e-9)):
        raise ValueError('hold_reference: finite position and a unit quaternion expected')
    v = np.zeros(6)

    def reference(t: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        return p, q, v

    return reference


# --------------------------------------------------------------------------- scenarios


@dataclass(frozen=True)
class StackConfig:
    """Everything a run needs, resolved from the shipped (or given) files.

    The ROS nodes build their objects from the same values (their parameters
    are the same YAML files), so a lockstep run and :func:`run_scenario` agree.
    """

    scenario: Scenario
    robot: RobotParams              # nominal robot, scenario overrides applied
    controller: ControllerConfig
    allocator: AllocatorConfig
    control_period: float           # s
    step_size: float = 0.01         # s

    @property
    def control_period_ns(self) -> int:
        return to_ns(self.control_period)

    @property
    def step_ns(self) -> int:
        return to_ns(self.step_size)

    def build_plant(self) -> Plant:
        """The plant at the scenario's initial state, with its disturbances."""
        init = self.scenario.initial_state
        return Plant(self.robot, self.scenario.disturbances, step_ns=self.step_ns,
                     position=init.position, quaternion=quat_from_euler(*init.euler),
                     nu=init.nu)

    def build_controller(self) -> Controller:
        return make_controller(self.controller, self.robot)

    def build_allocator(self, failed_thrusters: Sequence[int] = ()) -> ThrustAllocator:
        return self.allocator.build(self.robot, self.control_period, failed_thrusters)

    def describe(self) -> dict[str, Any]:
        """JSON-serialisable run description for RunLog.meta and bags (``backend``: the
        implementation that runs, ``numba`` or ``numpy``: core/jit.py)."""
        return {
            'scenario': self.scenario.name,
            'scenario_file': self.scenario.source,
            'controller': self.controller.kind,
            'allocator_mode': self.allocator.mode,
            'max_tilt_step': self.allocator.tilt_step(self.robot, self.control_period),
            'control_period': self.control_period,
            'step_size': self.step_size,
            'max_thrust': self.robot.max_thrust,
            'tilt_min': self.robot.tilt_min,
            'tilt_max': self.robot.tilt_max,
            'tilt_rate_limit': self.robot.tilt_rate_limit,
            'backend': jit.backend(),
            # What the steady-wrench oracle of the metrics needs (core/steady.py).
            'robot': self.robot.as_dict(),
            'disturbances': self.scenario.disturbances.describe(),
            'allocator_weights': list(self.allocator.weights),
            # Whether a run gets a hold verdict (core/hold.py): none with a failed thruster.
            'faults': [{'thruster': f.index + 1, 'at': f.at, 'detected_after': f.detected_after}
                       for f in self.scenario.faults],
        }


def stack_config(scenario: str | Path | Scenario, controller: str | None = None, *,
                 allocator_mode: str | None = None, robot_file: str | Path | None = None,
                 controller_file: str | Path | None = None,
                 allocator_file: str | Path | None = None,
                 step_size: float = 0.01) -> StackConfig:
    """Resolve a scenario (name, path or object) and the YAML files into a StackConfig.

    ``controller`` (pd | switching | pid) and ``allocator_mode`` (robust | paper)
    override the files' choices.
    """
    scn = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    robot = scn.robot(load_robot_params(robot_file))
    ctrl = load_controller_config(controller_file)
    if controller is not None:
        ctrl = ctrl.with_kind(controller)
    alloc = load_allocator_config(allocator_file)
    if allocator_mode is not None:
        alloc = AllocatorConfig.from_mapping({**asdict(alloc), 'mode': allocator_mode})
    return StackConfig(scn, robot, ctrl, alloc, load_control_period(robot_file), step_size)


def run_scenario(config: StackConfig, *, duration: float | None = None,
                 progress: Callable[[float], None] | None = None) -> RunLog:
    """Run a scenario headless: the same core objects, in the order the ROS stack uses.

    ``duration`` overrides the scenario's (s).
    """
    plant = config.build_plant()
    profile = config.scenario.reference
    return run(plant, config.build_controller(), config.build_allocator(),
               profile.at, config.scenario.duration if duration is None else duration,
               control_period_ns=config.control_period_ns, progress=progress,
               meta=config.describe(), faults=config.scenario.faults,
               rebuild_allocator=config.build_allocator)
