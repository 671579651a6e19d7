"""Figures of a campaign table (matplotlib Figure objects, rendered by Agg).

* ``cdf_final_position.png``: the distribution (empirical CDF) of the final
  position error per configuration, log scale; failed runs count as beyond
  the axis, so a curve that ends below 1 shows them;
* ``error_vs_current.png``: the final position error of every run against the
  mean current's speed and its direction (deg from north towards east), one
  marker per configuration, hollow for the runs that do not hold;
* ``verdicts.png``: per configuration, the runs that hold and those that do
  not by verdict (servo range, physics, control), stacked.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

from matplotlib.figure import Figure
import numpy as np

from tiltrov_ros.campaign.summary import final_position_error
from tiltrov_ros.campaign.table import PARAM, number
from tiltrov_ros.core.campaign import VERDICTS

_MARKERS = 'os^vD<>p'
_FLOOR_MM = 1e-3        # errors below are drawn here (log axes)
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
        ax.step(np.maximum(errors, _FLOOR_MM), fraction, where='post',
                label=f'{name} ({len(mine)} runs)')
    ax.set_xscale('log')
    ax.set_ylim(0.0, 1.02)
    ax.set_xlabel('final position error [mm] (mean |e| over the last 10 s, norm of x y z; '
                  f'floor {_FLOOR_MM:g})')
    ax.set_ylabel('fraction of runs')
    ax.grid(True, which='both', alpha=0.3)
    ax.legend(loc='lower right')
    fig.tight_layout()
    return fig


def current_figure(rows: Sequence[Mapping[str, str]], names: Sequence[str]) -> Figure:
    fig = Figure(figsize=(10.0, 4.2))
    speed_ax, direction_ax = fig.subplots(1, 2, sharey=True)
    for k, (name, mine) in enumerate(_by_configuration(rows, names).items()):
        for holds in (True, False):
            points = np.array([(number(r[PARAM + 'current_speed']),
                                number(r[PARAM + 'current_direction']), final_position_error(r))
                               for r in mine if (r['holds'] == '1') == holds
                               and final_position_error(r) is not None],
                              dtype=float).reshape(-1, 3)
            color = f'C{k}'
            style = {'marker': _MARKERS[k % len(_MARKERS)], 'linestyle': 'none', 'alpha': 0.7,
                     'color': color, 'markerfacecolor': color if holds else 'none',
                     'label': f'{name}, {"holds" if holds else "does not hold"}'}
            error = np.maximum(1e3 * points[:, 2], _FLOOR_MM)
            speed_ax.plot(points[:, 0], error, **style)
            direction_ax.plot(points[:, 1], error, **style)
    speed_ax.set_yscale('log')
    speed_ax.set_xlabel('current speed [m/s]')
    speed_ax.set_ylabel(f'final position error [mm] (floor {_FLOOR_MM:g})')
    direction_ax.set_xlabel('current direction [deg from north, towards east]')
    direction_ax.set_xticks(range(0, 361, 90))
    for ax in (speed_ax, direction_ax):
        ax.grid(True, which='both', alpha=0.3)
    handles, labels = speed_ax.get_legend_handles_labels()
    fig.legend(handles, labels, loc='upper center', ncol=min(4, len(labels)), frameon=False)
    fig.tight_layout(rect=(0.0, 0.0, 1.0, 0.9))
    return fig


#: Colours of the verdicts (held, servo range, physics, control).
_VERDICT_COLORS = ('#4c9a2a', '#3b75af', '#999999', '#c0392b')


def verdict_figure(rows: Sequence[Mapping[str, str]], names: Sequence[str]) -> Figure:
    fig = Figure(figsize=(max(6.0, 0.75 * len(names) + 2.5), 4.8))
    ax = fig.add_subplot()
    groups = _by_configuration(rows, names)
    x = np.arange(len(names))
    bottom = np.zeros(len(names))
    held = []
    for verdict, color in zip(VERDICTS, _VERDICT_COLORS):
        counts = np.array([sum(r['verdict'] == verdict for r in groups[n]) for n in names])
        ax.bar(x, counts, bottom=bottom, color=color, label=verdict.replace('_', ' '))
        bottom += counts
        held = held or list(counts)
    # The axis starts below the fewest runs held: the failures are the point.
    ax.set_ylim(max(0.0, min(held, default=0) - 0.1 * max(bottom, default=1)),
                max(bottom, default=1) * 1.01)
    ax.set_xticks(x, names, rotation=40, ha='right')
    ax.set_ylabel('runs (axis cut below)')
    ax.grid(True, axis='y', alpha=0.3)
    ax.legend(loc='upper center', bbox_to_anchor=(0.5, 1.12), ncol=len(VERDICTS),
              frameon=False)
    fig.tight_layout()
    return fig


def write_figures(rows: Sequence[Mapping[str, str]], names: Sequence[str], out: Path, *,
                  dpi: int = 100) -> list[Path]:
    """The figures into ``out``; their paths."""
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for stem, fig in (('cdf_final_position', cdf_figure(rows, names)),
                      ('error_vs_current', current_figure(rows, names)),
                      ('verdicts', verdict_figure(rows, names))):
        path = out / f'{stem}.png'
        fig.savefig(path, dpi=dpi, metadata=_PNG_METADATA)
        written.append(path)
    return written
