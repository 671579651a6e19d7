"""Benchmark of the robot model (not a test): plant step cost and headless real-time factor.

Measured in one run, so the ratios hold on any machine:

* microseconds per plant step with RK4 and with forward Euler (same model,
  same inputs), and their ratio;
* microseconds per step of the numpy reference (``rk4_step`` of
  ``dynamics.f``), to show what the straight-line float path saves;
* wall time and real-time factor of a headless 120 s run: 12 000 plant steps at
  10 ms, 2 400 control ticks at 50 ms.

The closed loop uses a small depth/attitude PD and a least-squares allocator at
fixed (vertical) tilts defined below, deliberately cheap so that the run
measures the plant and the runner: the real controllers and allocator are
timed by ``bench_allocation.py`` and, in the loop, by ``bench_lockstep.py``.

Run ``python bench/bench_plant.py``; ``main()`` returns the numbers as a dict
and prints a table (for ``tiltrov bench``).
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
import math
import time
from typing import Any

import numpy as np

from tiltrov_ros.core.disturbances import PAPER_COM_ERROR, Disturbances
from tiltrov_ros.core.dynamics import f
from tiltrov_ros.core.kinematics import Rquat
from tiltrov_ros.core.params import RobotParams, load_robot_params
from tiltrov_ros.core.plant import Plant, normalize_state_quaternion, rk4_step
from tiltrov_ros.core.runner import hold_reference, run
from tiltrov_ros.core.thrust_map import allocation_matrix


@dataclass
class _Output:
    wrench: np.ndarray
    tilt_request: tuple[float, float] | None = None


@dataclass
class _Result:
    thrusts: np.ndarray
    tilt_front: float
    tilt_rear: float
    achieved: np.ndarray
    feasible: bool


class StandInController:
    """PD on depth, roll and pitch: a cheap stand-in for the core controllers."""

    def update(self, t: float, position: np.ndarray, quaternion: np.ndarray, nu: np.ndarray,
               reference: Any) -> _Output:
        R = Rquat(quaternion)
        z_dot = (R @ nu[:3])[2]
        force = np.array([0.0, 0.0, 100.0 * (reference.position[2] - position[2])
                          - 150.0 * z_dot])
        K = -40.0 * R[2, 1] - 20.0 * nu[3]
        M = 40.0 * R[2, 0] - 20.0 * nu[4]
        return _Output(np.concatenate([R.T @ force, [K, M, 0.0]]))


class StandInAllocator:
    """Least squares on eq. (5) at fixed tilts: a cheap stand-in for the core allocator.

    The least-squares solution is the pseudo-inverse of B(tilts) = A G(tilts),
    cached per tilt pair.
    """

    def __init__(self, params: RobotParams, tilts: tuple[float, float]) -> None:
        self.params = params
        self.tilts = tilts
        self._cache: dict[tuple[float, float], tuple[np.ndarray, np.ndarray]] = {}

    def _matrices(self, tilt_front: float, tilt_rear: float) -> tuple[np.ndarray, np.ndarray]:
        key = (tilt_front, tilt_rear)
        if key not in self._cache:
            sa, ca = math.sin(tilt_front), math.cos(tilt_front)
            sb, cb = math.sin(tilt_rear), math.cos(tilt_rear)
            G = np.zeros((8, 4))
            G[[0, 1, 4, 5], [0, 1, 0, 1]] = [sa, sa, ca, ca]
            G[[2, 3, 6, 7], [2, 3, 2, 3]] = [sb, sb, cb, cb]
            B = allocation_matrix(self.params.length, self.params.width) @ G
            self._cache[key] = (B, np.linalg.pinv(B))
        return self._cache[key]

    def allocate_fixed(self, wrench: np.ndarray, tilt_front: float, tilt_rear: float,
                       previous: Any = None) -> _Result:
        B, B_pinv = self._matrices(tilt_front, tilt_rear)
        thrusts = np.clip(B_pinv @ wrench, -self.params.max_thrust, self.params.max_thrust)
        achieved = B @ thrusts
        return _Result(thrusts, tilt_front, tilt_rear, achieved,
                       float(np.max(np.abs(achieved - wrench))) < 1e-9)

    def allocate(self, wrench: np.ndarray, previous: Any = None) -> _Result:
        return self.allocate_fixed(wrench, *self.tilts, previous=previous)


def _plant(params: RobotParams, integrator: str) -> Plant:
    plant = Plant(params, Disturbances(com_error=PAPER_COM_ERROR, current=(0.1, 0.05, 0.0)),
                  integrator=integrator, nu=(0.2, -0.1, 0.05, 0.1, -0.2, 0.05))  # type: ignore[arg-type]
    plant.command([12.0, -8.0, 5.0, 10.0], [0.6, -0.3])
    return plant


def _us_per_step(params: RobotParams, integrator: str, steps: int, repeats: int) -> float:
    best = math.inf
    for _ in range(repeats):
        plant = _plant(params, integrator)
        plant.step(50)   # warm-up
        start = time.perf_counter()
        plant.step(steps)
        best = min(best, time.perf_counter() - start)
    return best / steps * 1e6


def _us_per_reference_step(params: RobotParams, steps: int) -> float:
    plant = _plant(params, 'rk4')
    x, tau, true = plant.state, plant.applied_wrench(), plant.params
    current = plant.current_velocity
    start = time.perf_counter()
    for _ in range(steps):
        x = normalize_state_quaternion(
            rk4_step(lambda t, xx: f(t, xx, tau, true, current), 0.0, x, 0.01))
    return (time.perf_counter() - start) / steps * 1e6


def main(argv: list[str] | None = None) -> dict[str, float]:
    """Run the benchmark, print a table, return the numbers."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--steps', type=int, default=5000,
                        help='plant steps per timing (default 5000)')
    parser.add_argument('--repeats', type=int, default=5, help='best of N (default 5)')
    parser.add_argument('--duration', type=float, default=120.0,
                        help='headless run length, s (default 120)')
    args = parser.parse_args(argv)

    params = load_robot_params()
    rk4 = _us_per_step(params, 'rk4', args.steps, args.repeats)
    euler = _us_per_step(params, 'euler', args.steps, args.repeats)
    reference = _us_per_reference_step(params, max(100, args.steps // 20))

    plant = Plant(params, Disturbances(com_error=PAPER_COM_ERROR))
    start = time.perf_counter()
    log = run(plant, StandInController(), StandInAllocator(params, (math.pi / 2, math.pi / 2)),
              hold_reference(position=(0.0, 0.0, 1.0)), args.duration)
    wall = time.perf_counter() - start

    results = {
        'rk4_step_us': rk4,
        'euler_step_us': euler,
        'rk4_over_euler': rk4 / euler,
        'reference_rk4_step_us': reference,
        'reference_over_fast_rk4': reference / rk4,
        'run_duration_s': args.duration,
        'run_plant_steps': float(len(log.t) - 1),
        'run_control_ticks': float(len(log.tc)),
        'run_wall_s': wall,
        'run_us_per_plant_step': wall / (len(log.t) - 1) * 1e6,
        'real_time_factor': args.duration / wall,
    }
    width = max(len(k) for k in results)
    print('bench_plant (stand-in controller and allocator)')
    for key, value in results.items():
        print(f'  {key:<{width}}  {value:12.3f}')
    return results


if __name__ == '__main__':
    main()
