"""``tiltrov bench``: run the benchmarks in ``bench/`` (a source checkout only).

Each ``bench/bench_<name>.py`` has a ``main()`` that prints a table and returns
a dict of numbers, ratios against a baseline measured in the same run. Speed is
measured here, never asserted in tests.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
from pathlib import Path
import sys
from typing import Any

from tiltrov_ros.paths import share_dir


def _bench_dir() -> Path:
    return share_dir() / 'bench'


def available() -> dict[str, Path]:
    """name -> file of every benchmark in the checkout (empty outside one)."""
    folder = _bench_dir()
    return {p.stem.removeprefix('bench_'): p for p in sorted(folder.glob('bench_*.py'))}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('names', nargs='*', metavar='NAME',
                        help='benchmarks to run (default: all); see --list')
    parser.add_argument('--list', action='store_true', help='list the benchmarks and exit')
    parser.add_argument('--json', type=Path, metavar='FILE',
                        help='also write all results to FILE as JSON')


def _load(path: Path) -> Any:
    spec = importlib.util.spec_from_file_location(f'tiltrov_bench_{path.stem}', path)
    if spec is None or spec.loader is None:
        raise ImportError(f'cannot load {path}')
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def run(args: argparse.Namespace) -> int:
    benches = available()
    if not benches:
        print(f'tiltrov bench: no benchmarks found in {_bench_dir()} (they live in a '
              'source checkout, not in an installed package)', file=sys.stderr)
        return 2
    if args.list:
        for name, path in benches.items():
            print(f'{name:12s} {path}')
        return 0
    unknown = [n for n in args.names if n not in benches]
    if unknown:
        print(f'tiltrov bench: unknown benchmark {unknown[0]!r}; available: '
              f'{", ".join(benches)}', file=sys.stderr)
        return 2
    results: dict[str, Any] = {}
    for name in args.names or list(benches):
        print(f'== {name}', flush=True)
        # A benchmark's main() parses the command line it sees: its own defaults here,
        # not ``tiltrov bench NAME`` (make bench failed with "unrecognized arguments").
        saved, sys.argv = sys.argv, [str(benches[name])]
        try:
            results[name] = _load(benches[name]).main()
        finally:
            sys.argv = saved
        print(flush=True)
    if args.json:
        args.json.write_text(json.dumps(results, indent=2, default=float) + '\n')
        print(f'results written to {args.json}')
    return 0
