"""Bounds on ``metrics.json``: the hold criterion of a campaign and of a single run.

A :class:`Bound` says ``metric[key] <= limit``, for the runs of the
controllers, allocator modes and gain sets it names; a run *holds* when it
meets every bound that applies to it (:func:`violations` lists the ones it
misses). Campaign files give them in their ``hold`` section
(:mod:`tiltrov_ros.core.campaign`); :mod:`tiltrov_ros.core.hold` judges a single
run with them. Nothing here imports the metrics, so they can use it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Protocol


class Selectable(Protocol):
    """What a bound is limited to: a run's controller, allocator mode and gain set."""

    @property
    def controller(self) -> str: ...

    @property
    def allocator(self) -> str: ...

    @property
    def gains(self) -> str: ...


@dataclass(frozen=True)
class Selection:
    """A run's controller, allocator mode and gain set ('' when it has no name)."""

    controller: str
    allocator: str
    gains: str = ''


@dataclass(frozen=True)
class Bound:
    """``metric[key] <= limit`` for every (key, limit) (key '' for a scalar metric), on
    the runs of the configurations it names (empty: all)."""

    metric: str
    limits: tuple[tuple[str, float], ...]
    controllers: tuple[str, ...] = ()
    allocators: tuple[str, ...] = ()
    gains: tuple[str, ...] = ()

    def applies(self, config: Selectable) -> bool:
        """Whether the bound applies to the runs of ``config`` (a campaign's
        :class:`~tiltrov_ros.core.campaign.Configuration`, or a :class:`Selection`)."""
        return ((not self.controllers or config.controller in self.controllers)
                and (not self.allocators or config.allocator in self.allocators)
                and (not self.gains or config.gains in self.gains))

    def violations(self, metrics: Mapping[str, Any]) -> list[str]:
        out = []
        for key, limit in self.limits:
            value = metrics.get(self.metric)
            name = self.metric
            if key:
                value = value.get(key) if isinstance(value, Mapping) else None
                name = f'{self.metric}.{key}'
            if not isinstance(value, (int, float)) or isinstance(value, bool):
                out.append(f'{name} is null')
            elif not value <= limit:
                out.append(f'{name} {value:.4g} > {limit:.4g}')
        return out


def violations(bounds: tuple[Bound, ...], metrics: Mapping[str, Any]) -> list[str]:
    """The bounds ``metrics`` misses, one line each (empty: the run holds)."""
    return [line for bound in bounds for line in bound.violations(metrics)]
