"""The record of one run, shared by the headless runner, the bag reader, the
metrics and the figures.

Two time grids, exactly as the ROS stack publishes them:

* the plant grid, one row per plant step: what ``odom`` and ``joint_states``
  carry;
* the control grid, one row per control tick: the ``setpoint`` and
  ``setpoint_velocity`` in force at the tick, and the ``wrench_cmd``,
  ``thrust_cmd``, ``tilt_cmd`` and ``wrench_achieved`` that answer it (all
  bearing the stamp of the ``odom`` message they answer).

``tiltrov sim`` fills it from the runner, ``tiltrov analyze`` from a bag; the
metrics and figures only ever see a :class:`RunLog`, so both give the same
numbers for the same run.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
import json
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

# name -> number of columns (0: a 1-D array)
PLANT_FIELDS: dict[str, int] = {
    't': 0,                 # s, sim time of the odom stamp
    'position': 3,          # m, base_link_frd origin in odom_ned
    'quaternion': 4,        # (w, x, y, z), body FRD orientation in odom_ned
    'nu': 6,                # body velocity (u v w p q r), m/s and rad/s
    'tilt_position': 2,     # rad, actual (tilt_front, tilt_rear)
    'tilt_velocity': 2,     # rad/s, actual
    'thrust': 4,            # N, actual thrust of thruster_1..4
}
CONTROL_FIELDS: dict[str, int] = {
    'tc': 0,                    # s, control tick (stamp of the odom it answers)
    'setpoint_position': 3,     # m, eta_d position in odom_ned
    'setpoint_quaternion': 4,   # (w, x, y, z), eta_d attitude
    'setpoint_velocity': 6,     # d(eta_d)/dt: (x y z) rates, (roll pitch yaw) rates
    'wrench_cmd': 6,            # N, N m, body frame
    'thrust_cmd': 4,            # N
    'tilt_cmd': 2,              # rad
    'wrench_achieved': 6,       # eq. (4) of thrust_cmd and tilt_cmd
}


@dataclass
class RunLog:
    """Time series of one run (see the module docstring for the two grids)."""

    t: FloatArray
    position: FloatArray
    quaternion: FloatArray
    nu: FloatArray
    tilt_position: FloatArray
    tilt_velocity: FloatArray
    thrust: FloatArray
    tc: FloatArray
    setpoint_position: FloatArray
    setpoint_quaternion: FloatArray
    setpoint_velocity: FloatArray
    wrench_cmd: FloatArray
    thrust_cmd: FloatArray
    tilt_cmd: FloatArray
    wrench_achieved: FloatArray
    # Run description: scenario, controller, allocator mode, robot limits
    # (max_thrust, tilt_min, tilt_max, tilt_rate_limit), ... JSON-serialisable.
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for spec, length_field in ((PLANT_FIELDS, 't'), (CONTROL_FIELDS, 'tc')):
            n = len(getattr(self, length_field))
            for name, cols in spec.items():
                value = np.asarray(getattr(self, name), dtype=float)
                expected = (n,) if cols == 0 else (n, cols)
                if value.shape != expected:
                    raise ValueError(f'RunLog.{name}: shape {value.shape}, expected {expected}')
                setattr(self, name, value)

    @classmethod
    def empty(cls, meta: dict[str, Any] | None = None) -> RunLog:
        arrays = {name: np.zeros((0,) if cols == 0 else (0, cols))
                  for name, cols in {**PLANT_FIELDS, **CONTROL_FIELDS}.items()}
        return cls(**arrays, meta=dict(meta or {}))

    def save_npz(self, path: str | Path) -> None:
        """Write every array and the JSON meta to one ``.npz`` file."""
        arrays = {f.name: getattr(self, f.name) for f in fields(self) if f.name != 'meta'}
        np.savez_compressed(path, **arrays, meta=np.array(json.dumps(self.meta)))

    @classmethod
    def load_npz(cls, path: str | Path) -> RunLog:
        with np.load(path, allow_pickle=False) as data:
            arrays = {name: data[name] for name in {**PLANT_FIELDS, **CONTROL_FIELDS}}
            meta = json.loads(str(data['meta']))
        return cls(**arrays, meta=meta)
