"""Figures of a campaign table (matplotlib Figure objects, rendered by Agg).

* ``cdf_final_position.png``: the distribution (empirical CDF) of the final
  position error per configuration, log scale; failed runs count as beyond
  the axis, so a curve that ends below 1 shows them;
* ``error_vs_current.png``: the final position error of every run against the
  mean current's speed and its direction (deg from north towards east), one
  marker per configuration.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

from matplotlib.figure import Figure
import numpy as np

from tiltrov_ros.campaign.summary import final_position_error
from tiltrov_ros.campaign.table import PARAM, number

_MARKERS = 'os^vD<>p'
_PNG_METADATA = {'Software': None}


def _by_configuration(rows: Sequence[Mapping[str, str]], names: Sequence[str]
                      ) -> dict[str, list[Mapping[str, str]]]:
    return {name: [r for r in rows if r['configuration'] == name] for name in names}


def cdf_figure(rows: Sequence[Mapping[str, str]], names: Sequence[str]) -> Figure:
    fig = Figure(figsize=(7.0, 4.5))
    ax = fig.add_subplot()
    for name, mine in _by_configuration(rows, names).items():
        errors = np.sort([1e3 * e for e in map(final_position_error, mine) if e is not None])
        if not len(mine) or not len(errors):
            continue
        fraction = np.arange(1, len(errors) + 1) / len(mine)
        ax.step(np.maximum(errors, 1e-3), fraction, where='post',
                label=f'{name} ({len(mine)} runs)')
    ax.set_xscale('log')
    ax.set_ylim(0.0, 1.02)
    ax.set_xlabel('final position error [mm] (mean |e| over the last 10 s, norm of x y z)')
    ax.set_ylabel('fraction of runs')
    ax.grid(True, which='both', alpha=0.3)
    ax.legend(loc='lower right')
    fig.tight_layout()
    return fig


def current_figure(rows: Sequence[Mapping[str, str]], names: Sequence[str]) -> Figure:
    fig = Figure(figsize=(10.0, 4.2))
    speed_ax, direction_ax = fig.subplots(1, 2, sharey=True)
    for k, (name, mine) in enumerate(_by_configuration(rows, names).items()):
        points = [(number(r[PARAM + 'current_speed']), number(r[PARAM + 'current_direction']),
                   final_position_error(r)) for r in mine]
        ok = np.array([p for p in points if p[2] is not None], dtype=float).reshape(-1, 3)
        style = {'marker': _MARKERS[k % len(_MARKERS)], 'linestyle': 'none', 'alpha': 0.7,
                 'label': name}
        speed_ax.plot(ok[:, 0], np.maximum(1e3 * ok[:, 2], 1e-3), **style)
        direction_ax.plot(ok[:, 1], np.maximum(1e3 * ok[:, 2], 1e-3), **style)
    speed_ax.set_yscale('log')
    speed_ax.set_xlabel('current speed [m/s]')
    speed_ax.set_ylabel('final position error [mm]')
    direction_ax.set_xlabel('current direction [deg from north, towards east]')
    direction_ax.set_xticks(range(0, 361, 90))
    for ax in (speed_ax, direction_ax):
        ax.grid(True, which='both', alpha=0.3)
    direction_ax.legend(loc='best')
    fig.tight_layout()
    return fig


def write_figures(rows: Sequence[Mapping[str, str]], names: Sequence[str], out: Path, *,
                  dpi: int = 100) -> list[Path]:
    """Both figures into ``out``; their paths."""
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for stem, fig in (('cdf_final_position', cdf_figure(rows, names)),
                      ('error_vs_current', current_figure(rows, names))):
        path = out / f'{stem}.png'
        fig.savefig(path, dpi=dpi, metadata=_PNG_METADATA)
        written.append(path)
    return written
