"""``tiltrov soak``: a long lockstep run of the whole stack, measured (``make soak``).

The stack runs as ``tiltrov launch --record`` runs it (separate processes,
lockstep, the recorder first), for ``--duration`` seconds of sim time (default
one hour). Measured:

* memory: the resident set size (VmRSS of /proc/PID/status) of each process,
  sampled every ``--sample-period`` wall seconds: the first sample once the
  run is going (after ``--warmup`` s), the last before the plant ends, and the
  largest;
* messages: per topic, how many the nodes published (their guarded
  publishers' counts, ``published.<topic>`` of the last ``/diagnostics`` each
  node sends, read from the bag) against how many the bag holds;
* the grid: every plant step and every control tick of the run on each of their
  topics in the bag (none missing);
* stalls (a tick that waited longer than ``stall_timeout``: count and longest, wall
  s), the recorder's pacing (waits, total wall s), and the real-time factor the plant
  achieved over the run (its ``/diagnostics``), first and last tenth compared.

Results go to ``--out``/soak.json and stdout; exit code 0 when the run ended
normally with nothing lost and no step or tick missing, 1 otherwise, 2 for bad
options. Stalls are reported, never a failure: a busy machine makes a run slower,
not wrong.
Linux only (/proc). Not part of ``make test`` (a seconds-long run is).
"""

from __future__ import annotations

import argparse
from collections.abc import Mapping
import json
from pathlib import Path
import sys
import time
from typing import Any

from tiltrov_ros.core.controllers import CONTROLLER_KINDS
from tiltrov_ros.core.names import DIAGNOSTICS, PLANT
from tiltrov_ros.stack.launch import launch
from tiltrov_ros.stack.specs import LaunchOptions
from tiltrov_ros.stack.supervisor import EXIT_FAILED, EXIT_OK, EXIT_USAGE, Monitor


def rss_kib(pid: int) -> int | None:
    """Resident set size of ``pid``, KiB (None if it is gone)."""
    try:
        with open(f'/proc/{pid}/status', encoding='ascii') as stream:
            for line in stream:
                if line.startswith('VmRSS:'):
                    return int(line.split()[1])
    except (OSError, ValueError):
        return None
    return None


class RssMonitor(Monitor):
    """Samples each node's RSS (see the module docstring)."""

    def __init__(self, period: float, warmup: float) -> None:
        self.period = period
        self.warmup = warmup
        self.started = time.monotonic()
        self._next = self.started + warmup
        self.first: dict[str, tuple[float, int]] = {}     # name -> (wall s, KiB)
        self.last: dict[str, tuple[float, int]] = {}
        self.peak: dict[str, int] = {}
        self.pids: dict[str, list[int]] = {}              # respawned nodes: several

    def _sample(self, pids: Mapping[str, int]) -> None:
        now = time.monotonic() - self.started
        for name, pid in pids.items():
            known = self.pids.setdefault(name, [])
            if pid not in known:
                known.append(pid)
            kib = rss_kib(pid)
            if kib is None:
                continue
            self.first.setdefault(name, (now, kib))
            self.last[name] = (now, kib)
            self.peak[name] = max(self.peak.get(name, 0), kib)

    def poll(self, pids: Mapping[str, int]) -> None:
        if time.monotonic() >= self._next:
            self._next = time.monotonic() + self.period
            self._sample(pids)

    def finished(self, pids: Mapping[str, int]) -> None:
        self._sample(pids)

    def table(self) -> dict[str, Any]:
        return {name: {'pids': self.pids.get(name, []),
                       'start_kib': self.first[name][1], 'start_at': self.first[name][0],
                       'end_kib': self.last[name][1], 'end_at': self.last[name][0],
                       'peak_kib': self.peak[name]}
                for name in self.first}


def _mean(values: list[float]) -> float | None:
    return sum(values) / len(values) if values else None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--duration', type=float, default=3600.0, metavar='SEC',
                        help='sim time to run, s (default 3600: one hour)')
    parser.add_argument('--scenario', default='pitch_hold', metavar='NAME|FILE',
                        help='scenario (default pitch_hold; its reference holds after its end)')
    parser.add_argument('--controller', choices=CONTROLLER_KINDS, default=None,
                        help="control law (default: config/wrench_controller.yaml's)")
    parser.add_argument('--out', type=Path, default=Path('runs/soak'), metavar='DIR',
                        help='output directory: bag/ and soak.json (default runs/soak)')
    parser.add_argument('--sample-period', type=float, default=10.0, metavar='SEC',
                        help='wall seconds between RSS samples (default 10)')
    parser.add_argument('--warmup', type=float, default=10.0, metavar='SEC',
                        help='wall seconds before the first ("start") RSS sample (default 10)')


def run(args: argparse.Namespace) -> int:
    out: Path = args.out
    bag = out / 'bag'
    if bag.exists():
        print(f'tiltrov soak: {bag} exists; choose another --out', file=sys.stderr)
        return EXIT_USAGE
    out.mkdir(parents=True, exist_ok=True)
    options = LaunchOptions(scenario=args.scenario, controller=args.controller,
                                     duration=args.duration, lockstep=True, record=bag)
    monitor = RssMonitor(args.sample_period, args.warmup)
    started = time.monotonic()
    code = launch(options, monitor=monitor)
    wall = time.monotonic() - started
    if code == EXIT_USAGE:
        return code
    if not bag.exists():
        print('tiltrov soak: no bag was written', file=sys.stderr)
        return EXIT_FAILED
    from tiltrov_ros.bag.losses import final_diagnostics, message_counts, missing_stamps
    from tiltrov_ros.core.timebase import to_ns
    from tiltrov_ros.stack.specs import resolve

    config, _ = resolve(options)
    diagnostics, statuses = final_diagnostics(bag)
    counts = message_counts(bag, diagnostics)
    plant = next((v for k, v in diagnostics.items() if k.rsplit('/', 1)[-1] == PLANT), {})
    rtf = [float(s['real_time_factor_achieved']) for s in statuses
           if s['_name'].rsplit('/', 1)[-1] == PLANT and 'real_time_factor_achieved' in s]
    tenth = max(1, len(rtf) // 10)
    result: dict[str, Any] = {
        'duration': args.duration, 'scenario': args.scenario, 'wall_seconds': wall,
        'launch_exit_code': code, 'rss': monitor.table(), 'messages': counts,
        'lost': {t: c['published'] - c['recorded'] for t, c in counts.items()
                 if c['published'] != c['recorded'] and t != DIAGNOSTICS},
        'missing_stamps': missing_stamps(bag, to_ns(args.duration), config.step_ns,
                                         config.control_period_ns),
        'stalls': int(plant.get('stalls', -1)),
        'longest_stall_s': float(plant.get('longest_stall_s', 0.0)),
        'recorder_waits': int(plant.get('recorder_waits', 0)),
        'recorder_wait_s': float(plant.get('recorder_wait_s', 0.0)),
        'sim_time_reached': float(plant.get('sim_time', 'nan')),
        'real_time_factor': {'first_tenth': _mean(rtf[:tenth]),
                             'last_tenth': _mean(rtf[-tenth:]), 'samples': len(rtf)},
    }
    (out / 'soak.json').write_text(json.dumps(result, indent=2) + '\n')
    print(f'soak: {args.duration:g} s of sim time in {wall:.1f} s wall, exit code {code}, '
          f'stalls {result["stalls"]} (longest {result["longest_stall_s"]:.2f} s), waits '
          f'for the recorder {result["recorder_waits"]} ({result["recorder_wait_s"]:.1f} s), '
          f'missing steps or ticks: {result["missing_stamps"] or "none"}')
    for name, row in result['rss'].items():
        print(f'  {name:20s} RSS {row["start_kib"] / 1024:7.1f} MiB at {row["start_at"]:6.0f} s'
              f' -> {row["end_kib"] / 1024:7.1f} MiB at {row["end_at"]:6.0f} s (peak '
              f'{row["peak_kib"] / 1024:.1f})')
    for topic, c in counts.items():
        print(f'  {topic:18s} published {c["published"]:9d}  recorded {c["recorded"]:9d}')
    r = result['real_time_factor']
    if r['first_tenth'] is not None:
        print(f'  real-time factor: first tenth {r["first_tenth"]:.1f}, last tenth '
              f'{r["last_tenth"]:.1f} ({r["samples"]} samples)')
    print(f'  written: {out / "soak.json"}, {bag}')
    ok = code == EXIT_OK and not result['lost'] and not result['missing_stamps']
    return EXIT_OK if ok else EXIT_FAILED
