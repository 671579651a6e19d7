"""``tiltrov campaign FILE --out DIR``: a Monte-Carlo campaign on Dask.

::

    tiltrov campaign config/campaigns/station_keeping.yaml --samples 200 --out runs/camp
    tiltrov campaign FILE --out DIR --resume                  # finish an interrupted one
    tiltrov campaign FILE --out DIR --scheduler tcp://HOST:8786   # on a Dask cluster
    tiltrov campaign FILE --out DIR --export s00042-pid-robust    # that run's files
    tiltrov campaign FILE --out DIR --robot robot_past_vertical   # another robot file

Into ``DIR``: ``runs.csv`` (one row per run, appended as runs finish:
:mod:`tiltrov_ros.campaign.table`), ``campaign.yaml`` (the campaign file as
run), ``summary.md`` and ``summary.json`` (:mod:`tiltrov_ros.campaign.summary`),
the figures (:mod:`tiltrov_ros.campaign.figures`) and ``worst/<run id>/``,
the files that run each worst run again with ``tiltrov sim``. The hold rate
per configuration is printed. Bad input ends with one line and exit code 2;
Ctrl-C (or SIGTERM) stops after flushing the table, exit code 130.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterator
from contextlib import contextmanager
import hashlib
import json
from pathlib import Path
import shutil
import signal
import sys
import time
from typing import Any

import yaml

from tiltrov_ros.analysis.runs import InputError, one_line
from tiltrov_ros.campaign.plan import Plan, RunTask
from tiltrov_ros.campaign.summary import comparison_rows, summarize, text_table, write_summary
from tiltrov_ros.campaign.table import PARAM, TABLE, RunTable, columns, read_table
from tiltrov_ros.campaign.worker import RunResult
from tiltrov_ros.core.campaign import CampaignSpec, Sample, draw_samples, load_campaign
from tiltrov_ros.core.errors import TiltrovError
from tiltrov_ros.core.params import robot_file
from tiltrov_ros.core.yamlfile import flatten
from tiltrov_ros.progress import ProgressBar

from .output import print_written, report_errors

EXIT_INTERRUPTED = 130


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('file', type=Path, metavar='FILE',
                        help='campaign file (YAML; e.g. config/campaigns/station_keeping.yaml)')
    parser.add_argument('--out', type=Path, required=True, metavar='DIR',
                        help='output directory: runs.csv, summary, figures, worst runs')
    parser.add_argument('--robot', metavar='FILE',
                        help='robot parameter file (or the name of a shipped one, e.g. '
                             'robot_past_vertical) every sample starts from (default: '
                             'config/robot.yaml)')
    parser.add_argument('--samples', type=int, metavar='N',
                        help="number of samples (default: the file's); sample i is the same "
                             'whatever N is')
    parser.add_argument('--resume', action='store_true',
                        help='continue the campaign in DIR: run only what runs.csv lacks')
    parser.add_argument('--scheduler', metavar='ADDRESS',
                        help='a running Dask scheduler, e.g. tcp://HOST:8786 (default: a '
                             'local cluster)')
    parser.add_argument('--workers', type=int, metavar='N',
                        help='local cluster: worker processes (default: one per core)')
    parser.add_argument('--batch-size', type=int, metavar='N',
                        help='runs per Dask task (default: about four tasks per worker, '
                             'at most 8 runs)')
    parser.add_argument('--worst', type=int, default=5, metavar='K',
                        help='worst runs per configuration listed and exported (default 5)')
    parser.add_argument('--export', nargs='+', metavar='RUN_ID',
                        help='only write these runs\' files (scenario, parameters, '
                             'reproduce.sh) into DIR/runs/RUN_ID/; nothing is run')
    parser.add_argument('--no-figures', action='store_true', help='skip the PNG figures')


def fingerprint(spec: CampaignSpec, robot: Path | None = None) -> str:
    """What must not change between a campaign and its --resume: the file's content
    (less ``samples``), its base scenarios and the ``--robot`` file's content."""
    assert spec.source is not None
    doc = yaml.safe_load(Path(spec.source).read_text(encoding='utf-8'))
    doc.pop('samples', None)
    content: dict[str, Any] = {'campaign': doc, 'bases': [dict(d) for _, d in spec.bases]}
    if robot is not None:
        content['robot'] = robot.read_text(encoding='utf-8')
    text = json.dumps(content, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def _check_out(spec: CampaignSpec, out: Path, resume: bool, robot: Path | None) -> None:
    marker = out / 'campaign.json'
    digest = fingerprint(spec, robot)
    if resume and marker.is_file():
        if json.loads(marker.read_text(encoding='utf-8')).get('fingerprint') != digest:
            raise InputError(f'{out} holds a campaign made from another campaign file (or '
                             f'other base scenarios, another --robot) than {spec.source}; use '
                             'another --out')
    out.mkdir(parents=True, exist_ok=True)
    if not (resume and marker.is_file()):
        marker.write_text(json.dumps({'campaign': spec.name, 'fingerprint': digest}) + '\n',
                          encoding='utf-8')
        (out / 'campaign.yaml').write_text(Path(str(spec.source)).read_text(encoding='utf-8'),
                                           encoding='utf-8')


def _row(task: RunTask, sample: Sample, spec: CampaignSpec, result: RunResult
         ) -> dict[str, Any]:
    config = spec.configuration(task.configuration)
    row: dict[str, Any] = {
        'run_id': task.run_id, 'sample': task.sample, 'configuration': config.name,
        'controller': config.controller, 'allocator': config.allocator, 'gains': config.gains,
        'status': 'ok' if result.metrics is not None else 'failed', 'error': result.error,
        'seconds': round(result.seconds, 4), 'worker': result.worker,
        'verdict': result.verdict, 'counterfactual_holds': result.counterfactual_holds,
        'counterfactual_violations': '; '.join(result.counterfactual_violations)}
    row['holds'] = int(result.metrics is not None and not result.violations)
    row['violations'] = '; '.join(result.violations)
    row.update({PARAM + k: v for k, v in sample.params.items()})
    row.update(flatten(result.metrics or {}))
    return row


def _duration(seconds: float) -> str:
    minutes, sec = divmod(round(seconds), 60)
    return f'{minutes // 60}h{minutes % 60:02d}m' if minutes >= 60 else f'{minutes}m{sec:02d}s'


@contextmanager
def _sigterm_interrupts() -> Iterator[None]:
    """SIGTERM (a batch system stopping the job) ends the campaign as Ctrl-C does."""

    def interrupt(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _execute(args: argparse.Namespace, spec: CampaignSpec, samples: list[Sample],
             todo: list[RunTask], table: RunTable, total: int) -> None:
    from tiltrov_ros.campaign.execute import dask_client, execute, worker_count

    by_sample = {s.index: s for s in samples}
    by_id = {t.run_id: t for t in todo}
    counts = {'done': 0, 'failed': 0}
    before = total - len(todo)
    with dask_client(args.scheduler, args.workers) as client:
        where = args.scheduler or 'a local cluster'
        print(f'running {len(todo)} runs on {where} ({worker_count(client)} workers)',
              flush=True)
        start = time.monotonic()
        with ProgressBar(f'campaign {spec.name}') as bar:
            def on_results(results: list[RunResult]) -> None:
                table.append(_row(by_id[r.run_id], by_sample[by_id[r.run_id].sample], spec, r)
                             for r in results)
                counts['done'] += len(results)
                counts['failed'] += sum(r.metrics is None for r in results)
                rate = counts['done'] / max(time.monotonic() - start, 1e-9)
                eta = _duration((len(todo) - counts['done']) / rate)
                bar((before + counts['done']) / total,
                    f'{before + counts["done"]}/{total} runs, {counts["failed"]} failed, '
                    f'ETA {eta}')

            execute(client, todo, on_results, size=args.batch_size)


def _summarize(args: argparse.Namespace, spec: CampaignSpec, plan: Plan, samples: int,
               ids: set[str]) -> list[Path]:
    out: Path = args.out
    _, rows = read_table(out / TABLE)
    rows = [r for r in rows if r['run_id'] in ids]
    summaries = summarize(spec, rows, worst=args.worst)
    by_id = {r['run_id']: r for r in rows}
    exported: dict[str, Path] = {}
    written: list[Path] = []
    shutil.rmtree(out / 'worst', ignore_errors=True)    # an earlier summary's worst runs
    for summary in summaries:
        for run_id in summary.worst:
            row = by_id[run_id]
            folder = out / 'worst' / run_id
            written += plan.export(int(row['sample']), row['configuration'], folder)
            exported[run_id] = folder
    figures: list[Path] = []
    if not args.no_figures and rows:
        from tiltrov_ros.campaign.figures import write_figures
        figures = write_figures(rows, [c.name for c in spec.configurations], out)
    written = [out / TABLE, *write_summary(spec, rows, summaries, out, samples=samples,
                                           exported=exported, figures=figures),
               *figures, *written]
    print(text_table(comparison_rows(summaries)))
    for summary in summaries:
        rate = '-' if summary.hold_rate is None else f'{100 * summary.hold_rate:.0f} %'
        why = ', '.join(f'{n} {v.replace("_", " ")}' for v, n in summary.verdicts.items())
        print(f'hold rate {summary.configuration}: {rate} ({summary.holds} of {summary.runs}'
              f' runs, {summary.failed} failed; not held: {why})')
    return written


def _export(args: argparse.Namespace, spec: CampaignSpec, plan: Plan) -> list[Path]:
    written: list[Path] = []
    names = [c.name for c in spec.configurations]
    for run_id in args.export:
        head, _, configuration = run_id.partition('-')
        if not (head[:1] == 's' and head[1:].isdigit() and configuration in names):
            raise InputError(f'--export: {run_id!r} is not a run of this campaign (s<sample>-'
                             f'<configuration>, configurations: {", ".join(names)})')
        written += plan.export(int(head[1:]), configuration, args.out / 'runs' / run_id)
    return written


def _check_dask() -> None:
    try:
        import tiltrov_ros.campaign.execute  # noqa: F401
    except ImportError as exc:
        raise InputError(f'Dask is missing ({one_line(exc)}): pip install dask distributed '
                         "(the package's campaign extra)") from exc


def _run(args: argparse.Namespace) -> int:
    for name, least in (('samples', 1), ('workers', 1), ('batch_size', 1), ('worst', 0)):
        value = getattr(args, name)
        if value is not None and value < least:
            raise InputError(f'--{name.replace("_", "-")} must be >= {least}, got {value}')
    try:
        spec = load_campaign(args.file)
        count = args.samples or spec.samples
        robot = robot_file(args.robot) if args.robot else None
        plan = Plan(spec, robot)
        if args.export:
            print_written(_export(args, spec, plan), args.out)
            return 0
        _check_dask()
        samples = draw_samples(spec, count)
        tasks = plan.tasks(samples)
        _check_out(spec, args.out, args.resume, robot)
        table = RunTable(args.out / TABLE, columns(samples[0].params), resume=args.resume)
    except TiltrovError as exc:
        raise InputError(one_line(exc)) from exc
    with table:
        todo = [t for t in tasks if t.run_id not in table.done]
        print(f'campaign {spec.name}: {count} samples x {len(spec.configurations)} '
              f'configurations = {len(tasks)} runs; {len(tasks) - len(todo)} already in '
              f'{table.path}', flush=True)
        if todo:
            try:
                with _sigterm_interrupts():
                    _execute(args, spec, samples, todo, table, len(tasks))
            except KeyboardInterrupt:
                # What the file holds, as --resume will read it: the interrupt may have
                # come between a row's write and its count (the row then went out here).
                table.close()
                in_file = {row['run_id'] for row in read_table(table.path)[1]}
                done = sum(t.run_id in in_file for t in tasks)
                print(f'tiltrov campaign: interrupted; {done} of {len(tasks)} runs are in '
                      f'{table.path}; the same command with --resume finishes the campaign',
                      file=sys.stderr)
                return EXIT_INTERRUPTED
            except TiltrovError as exc:
                raise InputError(one_line(exc)) from exc
    print_written(_summarize(args, spec, plan, count, {t.run_id for t in tasks}), args.out)
    return 0


def run(args: argparse.Namespace) -> int:
    return report_errors('tiltrov campaign', lambda: _run(args))


def main(argv: list[str] | None = None) -> int:
    """Run as ``python -m tiltrov_ros.cli.campaign`` (same as ``tiltrov campaign``)."""
    parser = argparse.ArgumentParser(prog='tiltrov campaign')
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == '__main__':
    sys.exit(main())
