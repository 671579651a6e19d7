"""``tiltrov analyze``: metrics and figures of recorded runs (bags), no ROS needed.

::

    tiltrov analyze runs/pd/bag --out runs/pd/analysis
    tiltrov analyze runs/pd/bag runs/switching/bag runs/pid/bag --out runs/compare
    tiltrov analyze runs/fleet/bag --namespace robot1 --out runs/robot1

Each bag is read into a :class:`~tiltrov_ros.core.runlog.RunLog` by
:func:`tiltrov_ros.bag.read_runlog` (header stamps, the stamp contract of
ARCHITECTURE.md), and from there everything is what ``tiltrov sim`` does with
the RunLog of a headless run: :func:`tiltrov_ros.analysis.runs.write_run`
(``run.npz``, ``control.csv``, ``metrics.json`` from
:func:`tiltrov_ros.core.metrics.compute_metrics`) and
:func:`tiltrov_ros.analysis.figures.write_figures`. So a lockstep bag and ``tiltrov sim``
of the same scenario give the same ``metrics.json``.

One bag: its files and figures go into ``--out``. Several bags: each bag's
files go into ``--out/<bag name>/`` (see :func:`bag_names`),
``--out/metrics.json`` maps each bag name to its metrics, and the figures,
runs overlaid, go into ``--out``. Runs are
labelled from the bag's ``run_info`` (controller, allocator, and the scenario
when the bags differ in it), else by the bag's name.

Bad input (no such bag, not a bag, a bag without the stack's topics) ends
with one line on stderr and exit code 2.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tiltrov_ros.analysis.runs import (
    InputError,
    one_line,
    write_run,
)
from tiltrov_ros.core.errors import BagError, TiltrovError
from tiltrov_ros.core.hold import HoldCriterion
from tiltrov_ros.core.metrics import write_metrics
from tiltrov_ros.core.names import normalize_namespace
from tiltrov_ros.core.runlog import RunLog

#: The topics (relative to the stack's namespace) without which a bag is not a
#: recording of the stack: the plant grid and the control grid.
REQUIRED_TOPICS = ('odom', 'wrench_cmd')


@dataclass
class Recording:
    """One bag read for the analysis."""

    name: str           # unique among the bags analyzed together
    path: Path
    log: RunLog


def bag_names(paths: Sequence[str | Path]) -> list[str]:
    """A name for each bag, unique among ``paths``: the bag directory's name
    (``runs/pd/bag`` -> ``bag``; a lone ``.mcap`` file's stem), with as many
    parent directories as it takes to tell equal names apart (``runs/pd/bag``
    and ``runs/pid/bag`` -> ``pd_bag``, ``pid_bag``), and ``_2``, ``_3`` ...
    for the same bag given twice."""
    from tiltrov_ros.bag.bagfile import resolve

    parts = []
    for path in paths:
        resolved = resolve(path)
        leaf = resolved if resolved.is_dir() else resolved.with_suffix('')
        parts.append(leaf.absolute().parts)
    depth = [1] * len(parts)

    def name(i: int) -> str:
        return '_'.join(p.strip('/') or 'root' for p in parts[i][-depth[i]:])

    while True:
        names = [name(i) for i in range(len(parts))]
        clash = [i for i, n in enumerate(names) if depth[i] < len(parts[i]) and any(
            names[j] == n and parts[j] != parts[i] for j in range(len(parts)))]
        if not clash:
            return unique_names(names)
        for i in clash:
            depth[i] += 1


def unique_names(names: Sequence[str]) -> list[str]:
    """``names`` with ``_2``, ``_3`` ... appended to repeats (``bag``, ``bag_2``)."""
    out: list[str] = []
    for name in names:
        candidate, k = name, 1
        while candidate in out:
            k += 1
            candidate = f'{name}_{k}'
        out.append(candidate)
    return out


def read_bag(path: str | Path, *, namespace: str | None = None,
             progress: bool | None = None) -> RunLog:
    """The RunLog of one bag, or :class:`InputError` (one line) when it is no
    recording of the stack.

    ``namespace`` None: the namespace of the bag's single ``odom`` topic.
    The metrics need the thrust limit: a bag whose ``run_info`` lacks
    ``max_thrust`` gets ``config/robot.yaml``'s (``meta['max_thrust_source']``
    says which).
    """
    from tiltrov_ros.bag.reader import read_runlog

    try:
        log = read_runlog(path, namespace=namespace, progress=progress)
    except (BagError, OSError) as exc:
        raise InputError(one_line(exc)) from exc
    counts = log.meta['bag']['message_counts']
    space = log.meta['bag']['namespace']
    missing = [f'{space}/{rel}' for rel in REQUIRED_TOPICS if not counts.get(f'{space}/{rel}')]
    if missing:
        raise InputError(f'{path}: no {" and no ".join(missing)} messages: not a recording of '
                         'the tiltrov stack' + ('' if namespace is not None else
                                                ' (pass --namespace?)'))
    if not isinstance(log.meta.get('max_thrust'), (int, float)):
        from tiltrov_ros.core.params import load_robot_params

        try:
            log.meta['max_thrust'] = load_robot_params().max_thrust
        except (TiltrovError, OSError) as exc:
            raise InputError(one_line(exc)) from exc
        log.meta['max_thrust_source'] = 'config/robot.yaml'
    return log


def run_labels(recordings: Sequence[Recording]) -> list[str]:
    """Legend text of each run: from its run_info (controller, a non-default
    allocator, the scenario when the runs differ in it), else the bag's name;
    the bag's name is appended where two labels would be equal."""
    from tiltrov_ros.analysis.figures import run_label

    scenarios = {r.log.meta.get('scenario') for r in recordings}
    labels = []
    for rec in recordings:
        meta = rec.log.meta
        if meta.get('controller') is None:
            labels.append(rec.name)
            continue
        label = run_label(rec.log)
        if len(scenarios) > 1 and meta.get('scenario'):
            label = f"{meta['scenario']}: {label}"
        labels.append(label)
    repeated = {label for label in labels if labels.count(label) > 1}
    return [f'{label} [{rec.name}]' if label in repeated and label != rec.name else label
            for label, rec in zip(labels, recordings)]


@dataclass
class Analysis:
    """What :func:`analyze` did."""

    written: list[Path]                     # files, in the order written
    metrics: dict[str, dict[str, Any]]      # bag name -> metrics.json content
    notes: list[str]                        # things the user should know (stderr)


def notes_of(rec: Recording) -> list[str]:
    """Remarks on a bag's content: values it lacks, the thrust limit assumed."""
    notes = []
    missing = rec.log.meta['bag'].get('missing') or {}
    if missing:
        notes.append(f'{rec.name}: values missing (NaN) from the bag: ' + ', '.join(
            f'{field} {count}' for field, count in sorted(missing.items())))
    if rec.log.meta.get('max_thrust_source'):
        notes.append(f"{rec.name}: run_info has no max_thrust; using "
                     f"{rec.log.meta['max_thrust_source']}'s {rec.log.meta['max_thrust']:g} N")
    return notes


def analyze(bags: Sequence[str | Path], out: Path, *, namespace: str | None = None,
            figures: bool = True, dpi: int = 100, progress: bool | None = None,
            criterion: HoldCriterion | None = None) -> Analysis:
    """Read ``bags``, write their files and figures into ``out`` (module docstring);
    metrics.json's ``hold`` by ``criterion`` (default: the shipped station-keeping one).

    Raises :class:`InputError` for a bag that cannot be analyzed (before
    anything is written) and OSError when the results cannot be written.
    """
    if not bags:
        raise InputError('no bag given')
    namespace = None if namespace is None else normalize_namespace(namespace)
    try:
        names = bag_names(bags)
    except BagError as exc:
        raise InputError(one_line(exc)) from exc
    recordings = [Recording(name, Path(bag), read_bag(bag, namespace=namespace,
                                                      progress=progress))
                  for name, bag in zip(names, bags)]
    result = Analysis([], {}, [note for rec in recordings for note in notes_of(rec)])
    single = len(recordings) == 1
    for rec in recordings:
        paths, result.metrics[rec.name] = write_run(rec.log, out if single else out / rec.name,
                                                    criterion)
        result.written += paths
    if not single:
        result.written.append(write_metrics(result.metrics, out / 'metrics.json'))
    if figures:
        from tiltrov_ros.analysis.figures import write_figures

        result.written += write_figures([r.log for r in recordings], out,
                                        labels=run_labels(recordings), dpi=dpi)
    return result
