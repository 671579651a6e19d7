"""``tiltrov analyze``: bags of known runs give their metrics, files and figures; bad input
gives one line and exit code 2.

The bags here are headless runs written by :func:`tiltrov_ros.bag.export.write_runlog_bag`
(no ROS); test_analyze_lockstep.py analyzes bags recorded from the live stack.
"""

from __future__ import annotations

from functools import cache
import json
from pathlib import Path

import numpy as np
import pytest

from tiltrov_ros import cli
from tiltrov_ros.analysis.analyze import analyze, bag_names, run_labels, unique_names
from tiltrov_ros.bag.export import write_runlog_bag
from tiltrov_ros.bag.writer import BagWriter
from tiltrov_ros.core import jit
from tiltrov_ros.core.metrics import compute_metrics
from tiltrov_ros.core.runlog import CONTROL_FIELDS, PLANT_FIELDS, RunLog
from tiltrov_ros.core.runner import run_scenario, stack_config


@cache
def headless(controller: str, duration: float = 2.0) -> RunLog:
    return run_scenario(stack_config('pitch_hold', controller), duration=duration)


def as_json(value: object) -> object:
    return json.loads(json.dumps(value))


def tiltrov(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    code = cli.main(['analyze', *args])
    out, err = capsys.readouterr()
    return code, out, err


def test_one_bag_gives_the_metrics_files_and_figures_of_its_run(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = headless('pd')
    bag = write_runlog_bag(log, tmp_path / 'pd_bag')
    out = tmp_path / 'out'
    code, stdout, err = tiltrov(capsys, str(bag), '--out', str(out), '--dpi', '40')
    assert code == 0, err
    assert err == ''
    metrics = json.loads((out / 'metrics.json').read_text())
    assert metrics == as_json(compute_metrics(log))
    assert metrics['run'] == {'scenario': 'pitch_hold', 'controller': 'pd',
                              'allocator_mode': 'robust', 'backend': jit.backend()}
    for name in ('run.npz', 'control.csv', 'errors.png', 'tilts.png', 'tracking.png',
                 'overlay.png', 'wrench_pd.png'):
        assert (out / name).stat().st_size > 0, name
    back = RunLog.load_npz(out / 'run.npz')
    for field in {**PLANT_FIELDS, **CONTROL_FIELDS}:
        np.testing.assert_array_equal(getattr(back, field), getattr(log, field), err_msg=field)
    assert back.meta['bag']['path'] == str(bag)
    assert stdout.startswith('pd_bag: final |e|')


def test_several_bags_each_in_its_folder_with_an_index_and_overlaid_figures(
        tmp_path: Path) -> None:
    logs = {kind: headless(kind) for kind in ('pd', 'switching', 'pid')}
    bags = [write_runlog_bag(log, tmp_path / kind / 'bag') for kind, log in logs.items()]
    out = tmp_path / 'out'
    result = analyze(bags, out, dpi=40)
    assert list(result.metrics) == ['pd_bag', 'switching_bag', 'pid_bag']
    index = json.loads((out / 'metrics.json').read_text())
    assert index == as_json(result.metrics)
    for name, log in zip(index, logs.values()):
        assert index[name] == as_json(compute_metrics(log))
        assert json.loads((out / name / 'metrics.json').read_text()) == index[name]
        assert (out / name / 'run.npz').is_file() and (out / name / 'control.csv').is_file()
    assert index['switching_bag']['run']['controller'] == 'switching'
    for name in ('errors.png', 'tilts.png', 'tracking.png', 'overlay.png', 'wrench_pd.png',
                 'wrench_switching.png', 'wrench_pid.png'):
        assert out / name in result.written, name
    assert not (out / 'bag' / 'errors.png').exists()


def test_labels_come_from_run_info_else_from_the_bag_name(tmp_path: Path) -> None:
    from tiltrov_ros.analysis.analyze import Recording, read_bag

    pd, pid = headless('pd'), headless('pid')
    paths = [write_runlog_bag(pd, tmp_path / 'a'),
             write_runlog_bag(pd, tmp_path / 'b', run_info={**pd.meta, 'allocator_mode': 'paper'}),
             write_runlog_bag(pid, tmp_path / 'c', run_info={**pid.meta, 'scenario': 'other'}),
             write_runlog_bag(pd, tmp_path / 'd'),
             write_runlog_bag(pd, tmp_path / 'no_info', run_info={})]
    recordings = [Recording(p.name, p, read_bag(p)) for p in paths]
    assert run_labels(recordings) == [
        'pitch_hold: PD (16), proposed [a]',
        'pitch_hold: PD (16), proposed, paper allocator',
        'other: PID',
        'pitch_hold: PD (16), proposed [d]',
        'no_info',
    ]
    assert run_labels(recordings[:2]) == ['PD (16), proposed',
                                          'PD (16), proposed, paper allocator']


def test_bag_without_run_info_is_analyzed_with_the_shipped_thrust_limit(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = headless('pd')
    bag = write_runlog_bag(log, tmp_path / 'plain', run_info={})
    code, _, err = tiltrov(capsys, str(bag), '--out', str(tmp_path / 'out'), '--no-figures')
    assert code == 0
    assert err.splitlines() == [
        "tiltrov analyze: note: plain: run_info has no max_thrust; using "
        "config/robot.yaml's 40 N"]
    metrics = json.loads((tmp_path / 'out' / 'metrics.json').read_text())
    expected = as_json(compute_metrics(log))
    assert metrics['run'] == {'scenario': None, 'controller': None, 'allocator_mode': None,
                              'backend': None}
    assert {k: v for k, v in metrics.items() if k != 'run'} == {
        k: v for k, v in expected.items() if k != 'run'}


def test_namespaced_stack(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = headless('pd')
    bag = write_runlog_bag(log, tmp_path / 'ns_bag', namespace='/robot1')
    for option in ([], ['--namespace', 'robot1'], ['--namespace', '/robot1/']):
        out = tmp_path / f'out{len(option)}'
        code, _, err = tiltrov(capsys, str(bag), '--out', str(out), '--no-figures', *option)
        assert code == 0, err
        assert json.loads((out / 'metrics.json').read_text()) == as_json(compute_metrics(log))
    code, _, err = tiltrov(capsys, str(bag), '--out', str(tmp_path / 'x'), '--namespace', 'r2')
    assert code == 2
    assert err.splitlines() == [f'tiltrov analyze: error: {bag} has no /r2/odom messages']


def _chatter_bag(path: Path) -> Path:
    from tiltrov_ros.bag.msgdefs import typestore

    store = typestore()
    with BagWriter(path) as bag:
        conn = bag.add_topic('/chatter', 'std_msgs/msg/String')
        bag.write(conn, 1, store.serialize_cdr(store.types['std_msgs/msg/String'](data='hi'),
                                               'std_msgs/msg/String'))
    return path


def _plant_only_bag(path: Path) -> Path:
    log = headless('pd')
    empty = {name: np.zeros((0,) if cols == 0 else (0, cols))
             for name, cols in CONTROL_FIELDS.items()}
    plant = {name: getattr(log, name) for name in PLANT_FIELDS}
    return write_runlog_bag(RunLog(**plant, **empty, meta=log.meta), path)


@pytest.mark.parametrize(('make', 'message'), [
    (lambda p: p / 'nothing', 'no bag at {p}/nothing'),
    (lambda p: (p / 'notes.txt').write_text('x') and p / 'notes.txt',
     '{p}/notes.txt is not a bag directory or an .mcap file'),
    (lambda p: (p / 'fake.mcap').write_bytes(b'not an mcap') and p / 'fake.mcap',
     'cannot open bag {p}/fake.mcap'),
    (lambda p: (p / 'empty').mkdir() or p / 'empty', '{p}/empty has no metadata.yaml'),
    (lambda p: _chatter_bag(p / 'chatter'), 'the bag has no odom topic'),
    (lambda p: _plant_only_bag(p / 'plant_only'),
     '{p}/plant_only: no /wrench_cmd messages: not a recording of the tiltrov stack '
     '(pass --namespace?)'),
])
def test_bad_input_is_one_line_and_exit_code_2(tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str],
                                               make, message: str) -> None:
    good = write_runlog_bag(headless('pd'), tmp_path / 'good')
    bad = make(tmp_path)
    out = tmp_path / 'out'
    code, stdout, err = tiltrov(capsys, str(good), str(bad), '--out', str(out))
    assert code == 2
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith('tiltrov analyze: error: '), err
    assert message.format(p=tmp_path) in lines[0]
    assert stdout == '' and not out.exists()       # nothing written


def test_bag_names_are_unique(tmp_path: Path) -> None:
    assert unique_names(['a', 'b', 'a', 'a', 'a_2']) == ['a', 'b', 'a_2', 'a_3', 'a_2_2']
    log = headless('pd')
    a = write_runlog_bag(log, tmp_path / 'runs' / 'pd' / 'bag')
    b = write_runlog_bag(log, tmp_path / 'runs' / 'pid' / 'bag')
    c = write_runlog_bag(log, tmp_path / 'other' / 'pd' / 'bag')
    d = write_runlog_bag(log, tmp_path / 'solo')
    mcap = next(d.glob('*.mcap'))
    assert bag_names([a, d]) == ['bag', 'solo']
    assert bag_names([a, b, a]) == ['pd_bag', 'pid_bag', 'pd_bag_2']
    assert bag_names([a, c, b]) == ['runs_pd_bag', 'other_pd_bag', 'pid_bag']
    assert bag_names([mcap]) == ['solo']               # the .mcap of a bag directory
