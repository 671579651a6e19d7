"""``tiltrov warmup``: compile (or load) every kernel ahead of use, group by group.

::

    tiltrov warmup                  # every group: allocation, plant, control, visual
    tiltrov warmup plant control

Prints the backend, where the compiled code is cached and, per group, the
seconds it took and whether numba compiled its kernels or loaded them from
the cache. ``make install`` runs it; run it once after a workspace install
(colcon) so that no node compiles at start. With the numpy backend (numba
absent, or ``TILTROV_BACKEND=numpy``) there is nothing to compile.
"""

from __future__ import annotations

import argparse
import sys

from tiltrov_ros.core import jit


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('groups', nargs='*', metavar='GROUP',
                        help=f'kernel groups (default: all: {", ".join(jit.GROUPS)})')


def run(args: argparse.Namespace) -> int:
    groups = list(args.groups) or list(jit.GROUPS)
    unknown = [g for g in groups if g not in jit.GROUPS]
    if unknown:
        print(f'tiltrov warmup: error: unknown group {unknown[0]!r}; groups: '
              f'{", ".join(jit.GROUPS)}', file=sys.stderr)
        return 2
    info = jit.describe()
    print(f'backend: {info["backend"]} ({info["reason"]})')
    if info['backend'] != 'numba':
        print('nothing to compile: the numpy reference runs')
        return 0
    print(f'cache:   {info["cache_dir"]}')
    total = 0.0
    for group in groups:
        with jit.compilations() as compiled:
            seconds = jit.warmup((group,), tell=False)
        kernels = len(jit.registered((group,)))
        total += seconds
        how = (f'compiled ({len(compiled)} functions)' if compiled
               else 'loaded from the cache' if kernels else 'none in this version')
        print(f'  {group:11s} {seconds:7.2f} s  {kernels} kernel(s): {how}')
    print(f'  {"total":11s} {total:7.2f} s')
    return 0
