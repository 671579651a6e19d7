"""``tiltrov launch``: the whole stack for one scenario, as processes or in one
process (no ``ros2 launch`` needed); the exit code says how it ended."""

from __future__ import annotations

import os
from pathlib import Path
import sys
import tempfile
from typing import IO

from tiltrov_ros.bag.losses import losses
from tiltrov_ros.core.errors import TiltrovError, UnreadableFileError
from tiltrov_ros.core.names import normalize_namespace

from .inprocess import run_single_process
from .specs import (
    LaunchError,
    LaunchOptions,
    dds_environment,
    namespaced_config,
    stack_specs,
)
from .supervisor import EXIT_FAILED, EXIT_OK, EXIT_USAGE, Monitor, Output, run_processes


def launch(options: LaunchOptions, stream: IO[str] | None = None, *,
           monitor: Monitor | None = None) -> int:
    """Run one launch; the exit code of ``tiltrov launch`` (``monitor``: see
    :func:`run_processes`; separate processes only)."""
    out = Output(stream if stream is not None else sys.stdout)
    namespace = normalize_namespace(options.namespace)
    try:
        if options.real_time_factor <= 0:
            raise LaunchError('--real-time-factor must be > 0')
        specs, config, duration = stack_specs(options)
    except UnreadableFileError as exc:     # a shipped parameter file, edited
        print(f'tiltrov launch: {exc}', file=sys.stderr)
        return EXIT_FAILED
    except (TiltrovError, FileNotFoundError) as exc:
        print(f'tiltrov launch: {exc}', file=sys.stderr)
        return EXIT_USAGE
    mode = 'lockstep' if options.lockstep else f'realtime x{options.real_time_factor:g}'
    summary = (f'{config.scenario.name} with {config.controller.kind} / '
               f'{config.allocator.mode}, {mode}: {duration:g} s of sim time')
    out.line('launch', f'{summary}{f" in {namespace}" if namespace else ""}'
                       f'{f", recording into {options.record}" if options.record else ""}')
    with tempfile.TemporaryDirectory(prefix='tiltrov_launch_') as tmp:
        if namespace:
            namespaced_config(specs, namespace, Path(tmp))
            specs, _, _ = stack_specs(options, config_dir=Path(tmp))
        if options.single_process:
            code = run_single_process(specs, namespace, out, summary, options.executor,
                                      status_file=options.status_file)
        else:
            env = dds_environment(os.environ)
            if options.executor:
                env['TILTROV_EXECUTOR'] = options.executor
            code = run_processes(specs, namespace, out, summary, Path(tmp), env,
                                 respawn=options.respawn, monitor=monitor,
                                 status_file=options.status_file)
    if options.record is not None and Path(options.record).exists():
        lost = report_losses(Path(options.record))
        if lost and code == EXIT_OK:
            code = EXIT_FAILED
    return code


def report_losses(bag: Path) -> bool:
    """Print one line per loss of the recording (bag/losses.py: topics short of what
    their publishers say they published, write errors, samples DDS reported lost);
    True if anything was lost or the bag cannot be read."""
    try:
        found = losses(bag)
    except TiltrovError as exc:
        print(f'tiltrov launch: failed: the recording lost data: the bag {bag} cannot be '
              f'read: {exc}', file=sys.stderr)
        return True
    if not found:
        return False
    print(f'tiltrov launch: failed: the recording lost data (tiltrov bag info {bag}):',
          file=sys.stderr)
    for line in found.lines():
        print(f'  {line}', file=sys.stderr)
    return True
