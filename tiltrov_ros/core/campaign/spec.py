"""What a campaign file says, validated: the dataclasses and the hold criterion.

See :mod:`tiltrov_ros.core.campaign` for the file and docs/campaign.md for
its format. Angles are in rad here, except in reference term templates,
which keep the file's unit (:attr:`CampaignSpec.angle_scale` converts).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np

from tiltrov_ros.core.bounds import Bound, violations
from tiltrov_ros.core.errors import CampaignError
from tiltrov_ros.core.hold import HOLD_TEMPLATE
from tiltrov_ros.core.metrics import compute_metrics
from tiltrov_ros.core.runlog import CONTROL_FIELDS, PLANT_FIELDS, RunLog

#: Robot keys whose values are angles (tilt limits) or angular rates (the servo).
ROBOT_ANGLE_KEYS = frozenset({'tilt_min', 'tilt_max', 'tilt_rate_limit'})
#: Per-DOF metrics whose values are times (s), not errors: their bounds are not angles.
TIME_METRICS = frozenset({'settling_time'})


@dataclass(frozen=True)
class Distribution:
    """A number drawn per sample: ``constant`` (args: value), ``uniform`` (low, high),
    ``normal`` (mean, std) or ``choice`` (the values)."""

    kind: str
    args: tuple[float, ...]

    def draw(self, rng: np.random.Generator) -> float:
        """One value (a constant consumes nothing from ``rng``)."""
        if self.kind == 'constant':
            return self.args[0]
        if self.kind == 'uniform':
            return float(rng.uniform(self.args[0], self.args[1]))
        if self.kind == 'normal':
            return float(rng.normal(self.args[0], self.args[1]))
        return self.args[int(rng.integers(len(self.args)))]

    def values(self) -> tuple[float, ...] | None:
        """Every value it can take when that is a finite set (constant, choice)."""
        return self.args if self.kind in ('constant', 'choice') else None


@dataclass(frozen=True)
class TermTemplate:
    """A reference term (scenario term types) whose numbers are distributions,
    present in a sample with ``probability`` (None: always, nothing drawn for it)."""

    kind: str
    fields: tuple[tuple[str, Distribution], ...]
    probability: float | None = None


@dataclass(frozen=True)
class VectorDraw:
    """Three numbers: one distribution per axis, or a ``magnitude`` in a direction drawn
    uniformly on the sphere."""

    axes: tuple[Distribution, ...] = ()
    magnitude: Distribution | None = None


@dataclass(frozen=True)
class CurrentDraw:
    """The mean ocean current: horizontal ``speed`` (m/s) towards ``direction`` (rad from
    north towards east) and a ``down`` component (m/s); or per NED axis (``axes``)."""

    speed: Distribution | None = None
    direction: Distribution | None = None
    down: Distribution | None = None
    axes: VectorDraw | None = None


@dataclass(frozen=True)
class PulseDraw:
    """An external body wrench pulse, present in a sample with ``probability``."""

    probability: float
    start: Distribution
    duration: Distribution
    wrench: tuple[Distribution, ...]


@dataclass(frozen=True)
class FaultDraw:
    """A failed thruster (1..4), present in a sample with ``probability``."""

    probability: float
    thruster: Distribution
    at: Distribution
    detected_after: Distribution


RobotValue = float | tuple[float, ...]


@dataclass(frozen=True)
class Configuration:
    """One way of controlling (and building) the robot that every sample runs with.

    ``levels``: the level of each robot factor (``compare.robot``), in the file's
    order; ``robot``: the robot keys they set (SI units, rad), over the drawn ones.
    """

    controller: str
    allocator: str
    gains: str
    name: str           # e.g. 'pid-robust' (plus '-<gains>' with several gain sets,
    #                     '-<level>' per robot factor)
    levels: tuple[str, ...] = ()
    robot: tuple[tuple[str, RobotValue], ...] = ()


@dataclass(frozen=True)
class CampaignSpec:
    """A validated campaign file (:func:`~tiltrov_ros.core.campaign.load_campaign`)."""

    name: str
    description: str
    seed: int
    samples: int
    duration: float | None
    angle_scale: float                          # file's angle unit -> rad
    bases: tuple[tuple[str, Mapping[str, Any]], ...]   # (label, scenario document)
    reference: tuple[tuple[str, tuple[TermTemplate, ...]], ...]
    current: CurrentDraw | None
    current_std: VectorDraw | None
    current_time_constant: VectorDraw | None
    com_error: VectorDraw | None
    pulses: tuple[PulseDraw, ...]
    robot: tuple[tuple[str, Distribution | tuple[Distribution, ...]], ...]   # scalar | vector
    fault: FaultDraw | None
    configurations: tuple[Configuration, ...]
    gain_sets: tuple[tuple[str, Mapping[str, Any]], ...]
    hold: tuple[Bound, ...]
    source: str | None = None
    #: The robot factors (``compare.robot``): (factor, its level names), file order.
    factors: tuple[tuple[str, tuple[str, ...]], ...] = ()

    @property
    def angle_unit(self) -> str:
        return 'rad' if self.angle_scale == 1.0 else 'deg'

    def configuration(self, name: str) -> Configuration:
        for config in self.configurations:
            if config.name == name:
                return config
        raise CampaignError(f'{self.source or "campaign"}: no configuration {name!r}; '
                            f'known: {", ".join(c.name for c in self.configurations)}')

    def bounds(self, config: Configuration) -> tuple[Bound, ...]:
        """The ``hold`` bounds that apply to the runs of ``config``."""
        return tuple(bound for bound in self.hold if bound.applies(config))

    def violations(self, config: Configuration, metrics: Mapping[str, Any]) -> list[str]:
        """The ``hold`` bounds a run of ``config`` misses (empty: the run holds)."""
        return violations(self.bounds(config), metrics)


@cache
def metrics_template() -> Mapping[str, Any]:
    """The keys and nesting of ``metrics.json`` (values of a run without ticks): what a
    hold bound may name and what the campaign table's metric columns are."""
    empty: dict[str, Any] = {name: np.zeros((0, n) if n else 0) for name, n in
                             {**PLANT_FIELDS, **CONTROL_FIELDS}.items()}
    template = compute_metrics(RunLog(**empty))
    template['hold'] = dict(HOLD_TEMPLATE)      # null without ticks: its keys, for tables
    return template
