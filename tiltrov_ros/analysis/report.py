"""The results page: the paper's two scenarios with every controller (``tiltrov report``).

``make figures`` runs ``tiltrov report --page docs/results.md``:

* pitch_hold (pd, pid, switching), pitch_hold_slow_servo (pd, pid) and
  trajectory (pd, pid, switching), headless, full length (:func:`run_scenarios`);
* the figures into ``docs/figures/`` (PNG, modest dpi): per scenario the
  errors (Fig. 5) and tilts (Fig. 6), the tracking figure (Fig. 7) of the
  trajectory, the wrench of pitch_hold with pd; and ``results.json`` with every
  run's metrics;
* between ``<!-- results:begin -->`` and ``<!-- results:end -->`` in the page:
  the gains used (config/wrench_controller.yaml), a table of final and RMS
  errors, a table of oscillation, tilt rate, saturation and feasibility, the
  paper's claims checked (:func:`checks`), and the figures. The section is
  appended if the markers are missing. Nothing in it depends on the machine or
  the clock, so running it twice changes nothing.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
import math
import os
from pathlib import Path
from typing import Any

from tiltrov_ros.analysis.runs import InputError, resolve, simulate
from tiltrov_ros.core.controllers import ControllerConfig
from tiltrov_ros.core.metrics import (
    FINAL_WINDOW,
    OSCILLATION_WINDOW,
)
from tiltrov_ros.core.names import DOF_NAMES
from tiltrov_ros.core.runlog import RunLog
from tiltrov_ros.core.runner import StackConfig

BEGIN = '<!-- results:begin -->'
END = '<!-- results:end -->'
#: (scenario, controllers) in the order of the tables.
RUNS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ('pitch_hold', ('pd', 'pid', 'switching')),
    ('pitch_hold_slow_servo', ('pd', 'pid')),
    ('trajectory', ('pd', 'pid', 'switching')),
)
#: figures per scenario (names of tiltrov_ros.analysis.figures), and which runs get a wrench figure.
FIGURES: dict[str, tuple[str, ...]] = {
    'pitch_hold': ('errors', 'tilts'),
    'pitch_hold_slow_servo': ('errors', 'tilts'),
    'trajectory': ('tracking', 'errors', 'tilts'),
}
WRENCH_FIGURES = (('pitch_hold', 'pd'),)
_DEG = 180.0 / math.pi


# --------------------------------------------------------------------------- formatting


def fmt(value: float | None) -> str:
    """A number for the tables: 0 below 5e-4, else 3 decimals below 1, 2 below 100."""
    if value is None or not math.isfinite(value):
        return 'n/a'
    v = abs(value)
    if v < 5e-4:
        return '0'
    if v < 1.0:
        return f'{value:.3f}'
    if v < 100.0:
        return f'{value:.2f}'
    return f'{value:.0f}'


def _triple(values: Mapping[str, float | None], names: Sequence[str], scale: float) -> str:
    return ' / '.join(fmt(None if values[n] is None else values[n] * scale)  # type: ignore[operator]
                      for n in names)


def _worst(values: Mapping[str, float | None], names: Sequence[str]) -> float:
    return max(float(values[n] or 0.0) for n in names)


def gains_table(config: ControllerConfig) -> str:
    """The gains and switching settings as Markdown."""
    g = config.gains
    lines = ['| gain | x | y | z | roll | pitch | yaw | unit |',
             '|---|---|---|---|---|---|---|---|']
    units = {'kp': 'N/m, N m/rad', 'kd': 'N s/m, N m s/rad', 'ki': 'N/(m s), N m/(rad s)',
             'integral_limit': 'N, N m'}
    for name in ('kp', 'kd', 'ki', 'integral_limit'):
        row = ' | '.join(f'{v:g}' for v in getattr(g, name))
        lines.append(f'| `{name}` | {row} | {units[name]} |')
    s = config.switching
    lines += ['', f'Switching baseline: hysteresis {s.hysteresis:g}, dwell {s.dwell_time:g} s, '
                  f'scales {s.position_scale:g} m and {s.angle_scale:g} rad, deadband '
                  f'{s.deadband:g}, settle {s.settle_time:g} s.']
    return '\n'.join(lines)


def errors_table(results: Sequence[tuple[StackConfig, dict[str, Any]]]) -> str:
    lines = ['| scenario | controller | final x / y / z [mm] | final roll / pitch / yaw [deg] '
             '| RMS x / y / z [mm] | RMS roll / pitch / yaw [deg] |',
             '|---|---|---|---|---|---|']
    for config, m in results:
        lines.append(
            f'| {config.scenario.name} | {config.controller.kind} '
            f"| {_triple(m['final_error'], DOF_NAMES[:3], 1e3)} "
            f"| {_triple(m['final_error'], DOF_NAMES[3:], _DEG)} "
            f"| {_triple(m['rms_error'], DOF_NAMES[:3], 1e3)} "
            f"| {_triple(m['rms_error'], DOF_NAMES[3:], _DEG)} |")
    return '\n'.join(lines)


def behaviour_table(results: Sequence[tuple[StackConfig, dict[str, Any]]]) -> str:
    lines = ['| scenario | controller | oscillation std x / z [mm], pitch [deg] '
             '| oscillation peak-to-peak x / z [mm], pitch [deg] '
             '| max tilt rate front / rear [deg/s] | servo travel front / rear [deg] '
             '| thrust saturation [% ticks] | infeasible [% ticks] |',
             '|---|---|---|---|---|---|---|---|']
    for config, m in results:
        osc, p2p = m['oscillation_std'], m['oscillation_peak_to_peak']
        sat, infeasible = m['thrust_saturation_fraction'], m['infeasible_fraction']
        lines.append(
            f'| {config.scenario.name} | {config.controller.kind} '
            f"| {fmt(osc['x'] * 1e3)} / {fmt(osc['z'] * 1e3)}, {fmt(osc['pitch'] * _DEG)} "
            f"| {fmt(p2p['x'] * 1e3)} / {fmt(p2p['z'] * 1e3)}, {fmt(p2p['pitch'] * _DEG)} "
            f"| {_triple(m['max_tilt_rate'], ('front', 'rear'), _DEG)} "
            f"| {_triple(m['servo_travel'], ('front', 'rear'), _DEG)} "
            f"| {fmt(None if sat is None else 100 * sat)} "
            f"| {fmt(None if infeasible is None else 100 * infeasible)} |")
    return '\n'.join(lines)


def checks(results: Sequence[tuple[StackConfig, dict[str, Any]]]) -> list[str]:
    """What the paper shows, checked on these results (PD holds without oscillating,
    the switching baseline oscillates, the PID removes the offsets, PD and PID track
    better than switching), one Markdown bullet each."""
    by = {(c.scenario.name, c.controller.kind): m for c, m in results}
    pos, ang = DOF_NAMES[:3], DOF_NAMES[3:]
    lines = []

    def check(ok: bool, text: str) -> None:
        lines.append(f"- {'yes' if ok else '**no**'}: {text}")

    pd = by.get(('pitch_hold', 'pd'))
    if pd:
        p, a = _worst(pd['oscillation_std'], pos), _worst(pd['oscillation_std'], ang)
        check(p < 1e-3 and a < 0.1 / _DEG,
              f'pitch_hold pd: error std over the last {OSCILLATION_WINDOW:g} s '
              f'{fmt(p * 1e3)} mm, {fmt(a * _DEG)} deg (limits 1 mm, 0.1 deg)')
    sw = by.get(('pitch_hold', 'switching'))
    if sw and pd:
        check(_worst(sw['oscillation_std'], pos) > 0.01,
              f"pitch_hold switching oscillates: std x {fmt(sw['oscillation_std']['x'] * 1e3)} "
              f"mm, pitch {fmt(sw['oscillation_std']['pitch'] * _DEG)} deg, peak-to-peak x "
              f"{fmt(sw['oscillation_peak_to_peak']['x'] * 1e3)} mm "
              f"(pd: std {fmt(pd['oscillation_std']['x'] * 1e3)} mm, "
              f"{fmt(pd['oscillation_std']['pitch'] * _DEG)} deg)")
    for scenario in ('pitch_hold', 'pitch_hold_slow_servo'):
        pid = by.get((scenario, 'pid'))
        if pid:
            p, a = _worst(pid['final_error'], pos), _worst(pid['final_error'], ang)
            check(p < 5e-3 and a < 0.2 / _DEG,
                  f'{scenario} pid: final error {fmt(p * 1e3)} mm, {fmt(a * _DEG)} deg '
                  f'(limits 5 mm, 0.2 deg)')
    sw = by.get(('trajectory', 'switching'))
    for kind in ('pd', 'pid'):
        m = by.get(('trajectory', kind))
        if m and sw:
            rms = math.sqrt(sum((m['rms_error'][d] or 0.0) ** 2 for d in pos))
            rms_sw = math.sqrt(sum((sw['rms_error'][d] or 0.0) ** 2 for d in pos))
            check(rms < rms_sw, f'trajectory {kind}: RMS position error {fmt(rms * 1e3)} mm '
                                f'< switching {fmt(rms_sw * 1e3)} mm')
    return lines


def caption(stem: str) -> str:
    """The caption of a report figure from its file stem (``<scenario>_<figure>``)."""
    # Longest name first: pitch_hold_slow_servo_tilts is not a pitch_hold figure.
    for scenario in sorted((name for name, _ in RUNS), key=len, reverse=True):
        if stem.startswith(scenario + '_'):
            what = stem[len(scenario) + 1:]
            break
    else:
        return stem
    text = {
        'errors': "errors eta_d - eta of the six DOFs, controllers overlaid (the paper's Fig. 5)",
        'tilts': "tilt angles, one panel per controller (the paper's Fig. 6)",
        'tracking': "path in the x-z plane and error norms (the paper's Fig. 7)",
        'overlay': 'pose and reference, controllers overlaid',
    }.get(what)
    if text is None and what.startswith('wrench_'):
        text = f'demanded and achieved body wrench, {what[len("wrench_"):]}'
    return f'{scenario}: {text or what}'


def build_section(results: Sequence[tuple[StackConfig, dict[str, Any]]],
                  figures: Sequence[str], *, duration: float | None = None) -> str:
    """The Markdown between the markers (``figures``: paths relative to the page)."""
    first = results[0][0]
    robot, alloc = first.robot, first.allocator
    shortened = (f'\n**Shortened to {duration:g} s per run (`--duration`): not the '
                 'scenarios\' numbers.**\n' if duration is not None else '')
    parts = [
        BEGIN,
        '<!-- generated by `make figures` (tiltrov report --page docs/results.md); '
        'edit tiltrov_ros/analysis/report.py, not this section -->',
        shortened,
        f'Headless runs (`tiltrov sim`), plant step {first.step_size * 1e3:g} ms, control '
        f'period {first.control_period * 1e3:g} ms, `{alloc.mode}` allocator, '
        f'center-of-mass error {list(first.scenario.disturbances.com_error)} m; '
        f'servo {robot.tilt_rate_limit * _DEG:g} deg/s except in pitch_hold_slow_servo. '
        f'Final = mean |e| over the last {FINAL_WINDOW:g} s; RMS over the whole run; '
        f'oscillation over the last {OSCILLATION_WINDOW:g} s (definitions: '
        '`tiltrov_ros/core/metrics.py`). 0 means below 0.0005 in the unit shown.',
        '',
        '**Gains** (`config/wrench_controller.yaml`):',
        '',
        gains_table(first.controller),
        '',
        '**Errors**:',
        '',
        errors_table(results),
        '',
        '**Oscillation, servos, saturation**:',
        '',
        behaviour_table(results),
        '',
        '**Checks** (what the paper shows):',
        '',
        *checks(results),
        '',
        *[line for f in figures for line in (f'![{Path(f).stem}]({f})', '',
                                             f'*{caption(Path(f).stem)}*', '')],
        END,
    ]
    return '\n'.join(parts)


def update_readme(text: str, section: str) -> str:
    """``text`` with the results section replaced (or appended under '## Results')."""
    begin, end = text.find(BEGIN), text.find(END)
    if begin >= 0 and end > begin:
        return text[:begin] + section + text[end + len(END):]
    if begin >= 0 or end >= 0:
        raise InputError(f'only one of the markers {BEGIN} and {END} is in the page')
    return text.rstrip('\n') + '\n\n## Results\n\n' + section + '\n'


# --------------------------------------------------------------------------- the command


def run_scenarios(duration: float | None = None) -> list[tuple[StackConfig, RunLog]]:
    out = []
    for scenario, kinds in RUNS:
        for kind in kinds:
            config = resolve(scenario, kind, None)
            out.append((config, simulate(config, duration)))
    return out


def write_report_figures(runs: list[tuple[StackConfig, RunLog]], out: Path, dpi: int) -> list[Path]:
    from tiltrov_ros.analysis.figures import write_figures
    written: list[Path] = []
    for scenario, _ in RUNS:
        logs = [log for config, log in runs if config.scenario.name == scenario]
        written += write_figures(logs, out, prefix=f'{scenario}_', which=FIGURES[scenario],
                                 dpi=dpi)
    for scenario, kind in WRENCH_FIGURES:
        logs = [log for config, log in runs
                if (config.scenario.name, config.controller.kind) == (scenario, kind)]
        written += write_figures(logs, out, prefix=f'{scenario}_', which=['wrench'], dpi=dpi)
    return written


def relative(path: Path, start: Path) -> str:
    return Path(os.path.relpath(path.resolve(), start.resolve())).as_posix()
