"""Benchmark (not a test): ``tiltrov analyze`` of a one-hour bag, against baselines.

A synthetic bag of the stack's topics at the stack's rates (odom, joint_states
and /clock at 100 Hz, setpoint, setpoint_velocity, wrench_cmd, tilt_cmd,
thrust_cmd and wrench_achieved at 20 Hz: 1.51 million messages for an hour)
is written with the project's writer (:func:`tiltrov_ros.bag.export.
write_runlog_bag`) from a headless pitch_hold run repeated end to end. Then,
in the same process:

* baseline ``iterate``: rosbags' Reader going over every message of the
  topics the analysis reads, without decoding them (any rosbags-based reader
  pays this);
* baseline ``npz``: the same RunLog from ``run.npz`` (:meth:`RunLog.load_npz`);
* baseline ``deserialize``: every message through rosbags' deserializer and the
  decoder's extraction, one by one (the reader before its batched decoding);
* ``read_runlog``: the bag into a RunLog;
* ``analyze``: all of ``tiltrov analyze`` (read, run.npz, control.csv,
  metrics.json, the five figures), with its parts.

::

    .venv/bin/python bench/bench_analyze.py                  # one hour
    .venv/bin/python bench/bench_analyze.py --duration 600 --bag /tmp/b   # keep the bag

``main()`` returns the numbers as a dict.
"""

from __future__ import annotations

import argparse
from pathlib import Path
import shutil
import sys
import tempfile
import time
from typing import Any

import numpy as np

from tiltrov_ros.bag.export import write_runlog_bag
from tiltrov_ros.core.runlog import CONTROL_FIELDS, PLANT_FIELDS, RunLog
from tiltrov_ros.core.runner import run_scenario, stack_config
from tiltrov_ros.core.timebase import seconds, to_ns

PIECE = 60.0    # s: the headless run repeated to fill the duration


def long_runlog(duration: float, piece: float = PIECE) -> RunLog:
    """``duration`` s of a headless pitch_hold pd run repeated end to end (plant rows
    every 10 ms, control rows every 50 ms, times continuing across the joins)."""
    piece = min(piece, duration)
    base = run_scenario(stack_config('pitch_hold', 'pd'), duration=piece)
    copies = int(np.ceil(duration / piece))
    step_ns, piece_ns = to_ns(float(base.t[1] - base.t[0])), to_ns(piece)
    plant_rows = len(base.t) - 1          # the last row is the next piece's first
    arrays: dict[str, Any] = {}
    for name in PLANT_FIELDS:
        values = getattr(base, name)[:plant_rows]
        arrays[name] = np.concatenate([values] * copies + [values[:1]])
    for name in CONTROL_FIELDS:
        arrays[name] = np.concatenate([getattr(base, name)] * copies)
    n_plant = to_ns(duration) // step_ns + 1
    for name in PLANT_FIELDS:
        arrays[name] = arrays[name][:n_plant]
    arrays['t'] = np.array([seconds(k * step_ns) for k in range(n_plant)])
    ticks = len(base.tc)
    tick_ns = [to_ns(float(t)) for t in base.tc]
    tc = [seconds(c * piece_ns + ns) for c in range(copies) for ns in tick_ns]
    n_control = sum(1 for t in tc if t < duration)
    for name in CONTROL_FIELDS:
        arrays[name] = arrays[name][:n_control]
    arrays['tc'] = np.array(tc[:n_control])
    assert ticks and len(arrays['tc']) == n_control
    meta = {**base.meta, 'duration': duration}
    return RunLog(**arrays, meta=meta)


def timed(fn: Any, *args: Any, **kwargs: Any) -> tuple[float, Any]:
    start = time.perf_counter()
    value = fn(*args, **kwargs)
    return time.perf_counter() - start, value


def iterate_raw(bag: Path, topics: set[str]) -> int:
    """Baseline: every message of ``topics`` through rosbags' Reader, not decoded."""
    from tiltrov_ros.bag.bagfile import open_reader

    count = 0
    with open_reader(bag) as reader:
        connections = [c for c in reader.connections if c.topic in topics]
        for _ in reader.messages(connections=connections):
            count += 1
    return count


def deserialize_all(bag: Path, decoders: dict[str, Any]) -> int:
    """Baseline: every message through rosbags' deserializer and the decoder's
    extraction, one by one (how the reader decoded before its batches)."""
    from tiltrov_ros.bag.bagfile import open_reader
    from tiltrov_ros.bag.msgdefs import typestore

    store = typestore()
    count = 0
    with open_reader(bag) as reader:
        connections = [c for c in reader.connections if c.topic in decoders]
        for conn, _, data in reader.messages(connections=connections):
            msg: Any = store.deserialize_cdr(data, conn.msgtype)
            decoders[conn.topic].extract(msg)
            count += 1
    return count


def warm(bag: Path) -> None:
    """Read the bag's files once, so every timed reader finds them in the page cache."""
    for path in bag.iterdir():
        with path.open('rb') as stream:
            while stream.read(1 << 24):
                pass


def main(argv: list[str] | None = None) -> dict[str, float]:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--duration', type=float, default=3600.0, metavar='SEC',
                        help='sim seconds in the bag (default 3600)')
    parser.add_argument('--bag', type=Path, default=None, metavar='DIR',
                        help='keep the bag here and reuse it when it exists (default: a '
                             'temporary directory, removed at the end)')
    parser.add_argument('--figures', action=argparse.BooleanOptionalAction, default=True,
                        help='include the figures in the analysis (default: yes)')
    parser.add_argument('--deserialize', action=argparse.BooleanOptionalAction, default=True,
                        help="time the per-message rosbags baseline too (default: yes)")
    args = parser.parse_args(argv)

    from tiltrov_ros.analysis.analyze import analyze
    from tiltrov_ros.bag.bagfile import bag_info
    from tiltrov_ros.bag.reader import RUNLOG_TOPICS, read_runlog

    tmp = Path(tempfile.mkdtemp(prefix='tiltrov_bench_analyze_'))
    out: dict[str, float] = {'duration': args.duration}
    try:
        bag = args.bag if args.bag is not None else tmp / 'bag'
        if not (bag / 'metadata.yaml').is_file():
            out['generate_runlog_s'], log = timed(long_runlog, args.duration)
            out['write_bag_s'], _ = timed(write_runlog_bag, log, bag)
        info = bag_info(bag)
        out['messages'] = float(info.message_count)
        out['bag_mb'] = sum(p.stat().st_size for p in bag.iterdir()) / 1e6
        topics = {f'/{rel}' for rel in RUNLOG_TOPICS}
        warm(bag)
        out['iterate_s'], count = timed(iterate_raw, bag, topics)
        out['read_messages'] = float(count)
        if args.deserialize:
            out['deserialize_s'], _ = timed(deserialize_all, bag, {
                f'/{rel}': decoder for rel, decoder in RUNLOG_TOPICS.items()})
        out['read_runlog_s'], log = timed(read_runlog, bag, progress=False)
        npz = tmp / 'run.npz'
        log.save_npz(npz)
        out['npz_s'], _ = timed(RunLog.load_npz, npz)
        result_dir = tmp / 'analysis'
        out['analyze_s'], result = timed(analyze, [bag], result_dir,
                                         figures=args.figures, progress=False)
        out['analyze_files'] = float(len(result.written))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)

    hours = args.duration / 3600
    print(f'one bag: {args.duration:g} s of sim time, {out["messages"]:.0f} messages, '
          f'{out["bag_mb"]:.0f} MB' + (f'; written in {out["write_bag_s"]:.1f} s'
                                        if 'write_bag_s' in out else ' (reused)'))
    rows = [
        ('baseline: iterate raw messages (rosbags)', out['iterate_s']),
        ('baseline: RunLog from run.npz', out['npz_s']),
        *([('baseline: rosbags deserialize per message', out['deserialize_s'])]
          if 'deserialize_s' in out else []),
        ('read_runlog (bag -> RunLog)', out['read_runlog_s']),
        ('tiltrov analyze' + ('' if args.figures else ' --no-figures'), out['analyze_s']),
    ]
    print(f'{"step":45s} {"s":>8s} {"s per hour":>11s} {"/iterate":>9s} {"msg/s":>11s}')
    for name, secs in rows:
        print(f'{name:45s} {secs:8.2f} {secs / hours:11.2f} {secs / out["iterate_s"]:9.2f} '
              f'{out["read_messages"] / secs:11.0f}')
    return out


if __name__ == '__main__':
    main(sys.argv[1:])
