"""Figures of one or several runs (matplotlib, no display needed).

Every function takes :class:`~tiltrov_ros.core.runlog.RunLog` objects, so
``tiltrov sim`` (runner) and ``tiltrov analyze`` (bags) draw the same figures.
The errors come from :func:`tiltrov_ros.core.metrics.control_errors`, the
same numbers as ``metrics.json``. Figures are built as
``matplotlib.figure.Figure`` objects and rendered by Agg when saved: pyplot and
its global backend are never touched.

* :func:`errors_figure` - the paper's Fig. 5: position errors x, y, z (mm) and
  attitude errors roll, pitch, yaw (deg), runs overlaid;
* :func:`tilts_figure` - Fig. 6: the tilt angles, one panel per run;
* :func:`tracking_figure` - Fig. 7: the path in the x-z plane and the position
  and attitude error norms, runs overlaid;
* :func:`wrench_figure` - demanded (``wrench_cmd``) and achieved wrench, six
  panels, one run;
* :func:`overlay_figure` - eta and eta_d of several runs, six panels;
* :func:`allocation_figure` - allocations of the same wrenches compared
  (``tiltrov replay --through allocator``).

:func:`write_figures` saves them under fixed names (``errors.png``,
``tilts.png``, ``tracking.png``, ``overlay.png``, ``wrench_<label>.png``, with
an optional prefix), without time stamps or version strings in the PNG, so the
same runs give the same files.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
import math
from pathlib import Path
import re

from matplotlib.axes import Axes
from matplotlib.figure import Figure
import numpy as np

from tiltrov_ros.core.metrics import control_errors
from tiltrov_ros.core.runlog import FloatArray, RunLog

CONTROLLER_LABELS = {
    'pd': 'PD (16), proposed',
    'pid': 'PID',
    'switching': 'selective switching [2]',
}
FIGURES = ('errors', 'tilts', 'tracking', 'overlay', 'wrench')
_DOF_LABELS = ('x error [mm]', 'y error [mm]', 'z error [mm]',
               'roll error [deg]', 'pitch error [deg]', 'yaw error [deg]')
# Display scale of each DOF: positions in mm (errors) or m (states), angles in deg.
_ERROR_SCALE = np.array([1e3, 1e3, 1e3, 180 / math.pi, 180 / math.pi, 180 / math.pi])
_STATE_SCALE = np.array([1.0, 1.0, 1.0, 180 / math.pi, 180 / math.pi, 180 / math.pi])
_STATE_LABELS = ('x [m]', 'y [m]', 'z [m] (NED, down)', 'roll [deg]', 'pitch [deg]',
                 'yaw [deg]')
_WRENCH_LABELS = ('X [N]', 'Y [N]', 'Z [N]', 'K [N m]', 'M [N m]', 'N [N m]')
_PNG_METADATA = {'Software': None}


def run_label(log: RunLog) -> str:
    """Legend text of a run: the controller's name (and a non-default allocator)."""
    controller = str(log.meta.get('controller', 'run'))
    label = CONTROLLER_LABELS.get(controller, controller)
    mode = log.meta.get('allocator_mode')
    if mode not in (None, 'robust'):
        label += f', {mode} allocator'
    return label


def _labels(logs: Sequence[RunLog], labels: Sequence[str] | None) -> list[str]:
    if labels is None:
        return [run_label(log) for log in logs]
    if len(labels) != len(logs):
        raise ValueError(f'{len(labels)} labels for {len(logs)} runs')
    return list(labels)


def _title(logs: Sequence[RunLog], what: str) -> str:
    """``'<scenarios>: <what>'``, or ``what`` alone for runs without a scenario (bags
    recorded without run_info)."""
    names = sorted({str(log.meta.get('scenario') or '') for log in logs} - {''})
    return f'{", ".join(names)}: {what}' if names else what


def _finish(fig: Figure, axes: Sequence[Axes], title: str, legend: bool = True) -> Figure:
    """Grid, a title on top and one legend for the whole figure at the bottom."""
    for ax in axes:
        ax.grid(True, alpha=0.3)
    height = fig.get_figheight()
    bottom = 0.0
    if legend:
        handles, names = axes[0].get_legend_handles_labels()
        if handles:
            fig.legend(handles, names, loc='lower center', ncol=min(len(handles), 4),
                       frameon=False)
            rows = math.ceil(len(handles) / 4)
            bottom = (0.1 + 0.28 * rows) / height
    if title:
        fig.suptitle(title, fontsize='medium')
    fig.tight_layout(rect=(0, bottom, 1, 1.0 - 0.1 / height if title else 1.0))
    return fig


def errors_figure(logs: Sequence[RunLog], labels: Sequence[str] | None = None) -> Figure:
    """The paper's Fig. 5: errors of the six DOFs (mm, deg), runs overlaid."""
    names = _labels(logs, labels)
    fig = Figure(figsize=(11, 6))
    axes = fig.subplots(2, 3, sharex=True).ravel()
    for log, name in zip(logs, names):
        err = control_errors(log)
        for k, ax in enumerate(axes):
            ax.plot(err.t, err.e[:, k] * _ERROR_SCALE[k], linewidth=1.0, label=name)
    for k, ax in enumerate(axes):
        ax.set_ylabel(_DOF_LABELS[k])
        ax.set_title(f'({"abcdef"[k]})', loc='left', fontsize='small')
        if k >= 3:
            ax.set_xlabel('time [s]')
    return _finish(fig, axes, _title(logs, 'error eta_d - eta'))


def tilts_figure(logs: Sequence[RunLog], labels: Sequence[str] | None = None) -> Figure:
    """The paper's Fig. 6: actual tilt angles (deg), commands dotted; one panel per run."""
    names = _labels(logs, labels)
    fig = Figure(figsize=(9, 2.6 * len(logs) + 0.6))
    axes = np.atleast_1d(fig.subplots(len(logs), 1, sharex=True, squeeze=False)[:, 0])
    for i, (ax, log, name) in enumerate(zip(axes, logs, names)):
        deg = 180 / math.pi
        for j, (servo, color) in enumerate((('front (alpha)', 'C0'), ('rear (beta)', 'C3'))):
            ax.plot(log.t, log.tilt_position[:, j] * deg, color=color, linewidth=1.2,
                    label=f'{servo}, actual')
            ax.step(log.tc, log.tilt_cmd[:, j] * deg, where='post', color=color,
                    linewidth=0.6, linestyle=':', label=f'{servo}, command')
        ax.set_ylabel('tilt [deg]')
        ax.set_title(f'({"abcdefghijklmnopqrstuvwxyz"[i % 26]}) {name}', loc='left',
                     fontsize='small')
        ax.set_ylim(-100, 100)
        ax.set_yticks([-90, -45, 0, 45, 90])
    axes[-1].set_xlabel('time [s]')
    return _finish(fig, list(axes), _title(logs, 'tilt angles'))


def tracking_figure(logs: Sequence[RunLog], labels: Sequence[str] | None = None) -> Figure:
    """The paper's Fig. 7: x-z path, position error norm (mm), attitude error norm (deg)."""
    names = _labels(logs, labels)
    fig = Figure(figsize=(13, 4.2))
    ax_path, ax_pos, ax_att = fig.subplots(1, 3)
    reference_drawn = False
    for log, name in zip(logs, names):
        err = control_errors(log)
        if not reference_drawn and len(err.t):
            ax_path.plot(err.eta_d[:, 0], err.eta_d[:, 2], color='k', linestyle='--',
                         linewidth=1.0, label='reference')
            reference_drawn = True
        line = ax_path.plot(err.eta[:, 0], err.eta[:, 2], linewidth=1.0, label=name)[0]
        ax_pos.plot(err.t, np.linalg.norm(err.e[:, :3], axis=1) * 1e3, linewidth=1.0,
                    color=line.get_color(), label=name)
        ax_att.plot(err.t, np.linalg.norm(err.e[:, 3:], axis=1) * 180 / math.pi,
                    linewidth=1.0, color=line.get_color(), label=name)
    ax_path.invert_yaxis()                       # NED: z down, so up is up on the page
    ax_path.set_xlabel('x [m]')
    ax_path.set_ylabel('z [m] (NED, down)')
    ax_path.set_title('(a) path in the x-z plane', loc='left', fontsize='small')
    ax_pos.set_xlabel('time [s]')
    ax_pos.set_ylabel('position error |e_xyz| [mm]')
    ax_pos.set_title('(b) position error', loc='left', fontsize='small')
    ax_att.set_xlabel('time [s]')
    ax_att.set_ylabel('attitude error |e_rpy| [deg]')
    ax_att.set_title('(c) orientation error', loc='left', fontsize='small')
    return _finish(fig, [ax_path, ax_pos, ax_att], _title(logs, 'tracking'))


def wrench_figure(log: RunLog, label: str | None = None) -> Figure:
    """Demanded and achieved body wrench of one run, six panels."""
    fig = Figure(figsize=(11, 6))
    axes = fig.subplots(2, 3, sharex=True).ravel()
    for k, ax in enumerate(axes):
        ax.step(log.tc, log.wrench_cmd[:, k], where='post', linewidth=1.4, color='C0',
                label='demanded (wrench_cmd)')
        ax.step(log.tc, log.wrench_achieved[:, k], where='post', linewidth=0.9, color='C1',
                linestyle='--', label='achieved (eq. (4))')
        ax.set_ylabel(_WRENCH_LABELS[k])
        if k >= 3:
            ax.set_xlabel('time [s]')
    name = label if label is not None else run_label(log)
    return _finish(fig, axes, _title([log], f'body wrench, {name}'))


def overlay_figure(logs: Sequence[RunLog], labels: Sequence[str] | None = None) -> Figure:
    """eta (solid) of several runs and the reference eta_d (dashed), six panels."""
    names = _labels(logs, labels)
    fig = Figure(figsize=(11, 6))
    axes = fig.subplots(2, 3, sharex=True).ravel()
    for i, (log, name) in enumerate(zip(logs, names)):
        err = control_errors(log)
        for k, ax in enumerate(axes):
            if i == 0:
                ax.plot(err.t, err.eta_d[:, k] * _STATE_SCALE[k], color='k', linestyle='--',
                        linewidth=1.0, label='reference')
            ax.plot(err.t, err.eta[:, k] * _STATE_SCALE[k], linewidth=1.0, label=name)
    for k, ax in enumerate(axes):
        ax.set_ylabel(_STATE_LABELS[k])
        if k >= 3:
            ax.set_xlabel('time [s]')
    return _finish(fig, axes, _title(logs, 'pose and reference'))


def allocation_figure(t: FloatArray, weighted_error: Mapping[str, FloatArray],
                      tilts: Mapping[str, FloatArray], title: str = '') -> Figure:
    """Allocations of the same wrenches compared (``tiltrov replay --through allocator``).

    (a) the weighted wrench error ||W (achieved - demanded)|| of each over time
    (symmetric log scale: exact answers sit at 0); (b), (c) the commanded tilts
    alpha and beta (deg) of each.
    """
    fig = Figure(figsize=(11, 7.5))
    ax_err, ax_front, ax_rear = fig.subplots(3, 1, sharex=True)
    styles = ('-', '--', ':', '-.')
    deg = 180 / math.pi
    for i, (name, error) in enumerate(weighted_error.items()):
        style = styles[i % len(styles)]
        ax_err.step(t, error, where='post', linestyle=style, linewidth=1.0, label=name)
        ax_front.step(t, tilts[name][:, 0] * deg, where='post', linestyle=style, linewidth=1.0,
                      label=name)
        ax_rear.step(t, tilts[name][:, 1] * deg, where='post', linestyle=style, linewidth=1.0,
                     label=name)
    ax_err.set_yscale('symlog', linthresh=1e-3)
    ax_err.set_ylabel('weighted wrench error')
    ax_err.set_title('(a) ||W (achieved - wrench_cmd)||', loc='left', fontsize='small')
    ax_front.set_ylabel('tilt_front [deg]')
    ax_front.set_title('(b) front tilt (alpha), commanded', loc='left', fontsize='small')
    ax_rear.set_ylabel('tilt_rear [deg]')
    ax_rear.set_title('(c) rear tilt (beta), commanded', loc='left', fontsize='small')
    ax_rear.set_xlabel('time [s]')
    heading = 'allocation of the recorded wrench_cmd'
    return _finish(fig, [ax_err, ax_front, ax_rear], f'{title}: {heading}' if title else heading)


def _slug(text: str) -> str:
    return re.sub(r'[^A-Za-z0-9_.-]+', '_', text).strip('_') or 'run'


def save(fig: Figure, path: str | Path, *, dpi: int = 100) -> Path:
    """Save as PNG without a software/version tag (same input, same bytes)."""
    target = Path(path)
    fig.savefig(target, dpi=dpi, metadata=_PNG_METADATA)
    return target


def write_figures(logs: Sequence[RunLog], out_dir: str | Path, *, prefix: str = '',
                  labels: Sequence[str] | None = None, which: Sequence[str] = FIGURES,
                  dpi: int = 100) -> list[Path]:
    """Write the figures named in ``which`` for ``logs`` into ``out_dir``; return the paths.

    Names: ``<prefix>errors.png``, ``<prefix>tilts.png``, ``<prefix>tracking.png``,
    ``<prefix>overlay.png`` and one ``<prefix>wrench_<controller>.png`` per run
    (its label for a run without a controller in its meta; ``_2``, ``_3`` ...
    when two runs share a controller).
    """
    unknown = set(which) - set(FIGURES)
    if unknown:
        raise ValueError(f'unknown figure {sorted(unknown)[0]!r}; known: {", ".join(FIGURES)}')
    if not logs:
        raise ValueError('no runs to draw')
    names = _labels(logs, labels)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    builders = {'errors': errors_figure, 'tilts': tilts_figure, 'tracking': tracking_figure,
                'overlay': overlay_figure}
    for key in FIGURES:
        if key not in which:
            continue
        if key == 'wrench':
            seen: dict[str, int] = {}
            for log, name in zip(logs, names):
                stem = _slug(str(log.meta.get('controller') or name))
                seen[stem] = seen.get(stem, 0) + 1
                suffix = '' if seen[stem] == 1 else f'_{seen[stem]}'
                written.append(save(wrench_figure(log, name),
                                    out / f'{prefix}wrench_{stem}{suffix}.png', dpi=dpi))
        else:
            written.append(save(builders[key](logs, names), out / f'{prefix}{key}.png',
                                dpi=dpi))
    return written
