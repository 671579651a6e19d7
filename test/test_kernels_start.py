"""How the compiled kernels start (core/jit.py): nothing compiles after construction, even
on a cold cache; a sealed kernel refuses new types; a read-only install caches where it
can write; without numba (or with TILTROV_BACKEND=numpy) the numpy reference runs, with
one warning when numba is missing. Each case runs in a fresh process."""

from __future__ import annotations

import json
import os
from pathlib import Path
import shutil
import subprocess
import sys
from typing import Any

from harness import HANG_BOUND, run_while_progressing
import numpy as np
import pytest

from tiltrov_ros.core import jit
from tiltrov_ros.core.metrics import compute_metrics, metric_differences
from tiltrov_ros.core.params import load_robot_params
from tiltrov_ros.core.plant import Plant
from tiltrov_ros.core.plant_kernels import plant_steps
from tiltrov_ros.core.runner import run_scenario, stack_config

REPO = Path(__file__).resolve().parent.parent
SIM = ['sim', '--scenario', 'pitch_hold', '--controller', 'pid', '--duration', '0.5',
       '--no-figures']

needs_numba = pytest.mark.skipif(not jit.compiled(), reason='numba is not the backend here')
#: Compiling every kernel from nothing takes 37 s of CPU time (159 s of wall time was seen
#: on a 2-core machine running other jobs): the commands run to their end while they use
#: CPU, and only a hang fails them.
pytestmark = pytest.mark.timeout(HANG_BOUND)


def _env(**changes: str | None) -> dict[str, str]:
    env = dict(os.environ)
    for key in ('NUMBA_CACHE_DIR', 'XDG_CACHE_HOME', jit.BACKEND_ENV):
        env.pop(key, None)
    for key, value in changes.items():
        if value is None:
            env.pop(key, None)
        else:
            env[key] = value
    return env


def _python(code: str, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    return run_while_progressing([sys.executable, '-c', code], env=env, cwd=REPO)


def _last_json(stdout: str) -> dict[str, Any]:
    value: dict[str, Any] = json.loads(stdout.strip().splitlines()[-1])
    return value


# -- nothing compiles after construction ------------------------------------------------

@pytest.mark.slow
@needs_numba
def test_on_a_cold_cache_the_constructors_compile_everything_a_run_uses(tmp_path: Path) -> None:
    """The four stack nodes in-process (real rclpy context) and the runner's objects on an
    empty NUMBA_CACHE_DIR; then a second of lockstep and headless runs of every
    controller: numba compiles nothing and loads nothing more."""
    cache = tmp_path / 'cache'
    cache.mkdir()
    result = run_while_progressing(
        [sys.executable, str(REPO / 'test' / 'kernel_start.py'), 'stack'], cwd=REPO,
        env=_env(NUMBA_CACHE_DIR=str(cache)))
    assert result.returncode == 0, result.stderr
    # A cold cache is said, once per node's groups, before the compiler's silent minute.
    told = [line for line in result.stderr.splitlines() if 'tiltrov_ros: compiling the' in line]
    assert told and all(f'into {cache} (about ' in line and '`tiltrov warmup` does it ahead'
                        in line for line in told), result.stderr
    report = _last_json(result.stdout)
    assert report['backend'] == 'numba' and report['cache_dir'] == str(cache)
    assert {'plant', 'control'} <= set(report['registered'].values())
    nodes = report['nodes']
    assert set(nodes) == {'plant_simulator', 'wrench_controller', 'thrust_allocator',
                          'reference_publisher'}
    assert all(n['sealed'] for n in nodes.values())
    assert nodes['plant_simulator']['warmup'] > 0.0      # it did compile: the cache was cold
    assert report['sealed'] and report['stack_finished']
    assert report['compiled_after_construction'] == []
    assert report['loaded_after_construction'] == []
    assert any(cache.rglob('*.nbi'))


@needs_numba
def test_the_runners_objects_warm_themselves() -> None:
    result = run_while_progressing(
        [sys.executable, str(REPO / 'test' / 'kernel_start.py'), 'runner'], cwd=REPO,
        env=_env())
    assert result.returncode == 0, result.stderr
    assert 'compiling the' not in result.stderr      # loaded from the warm cache: not said
    report = _last_json(result.stdout)
    assert report['sealed'] and {'plant', 'control'} <= set(report['registered'].values())
    assert report['compiled_after_construction'] == []
    assert report['loaded_after_construction'] == []


@needs_numba
def test_a_sealed_kernel_refuses_new_types_instead_of_compiling() -> None:
    plant = Plant(load_robot_params())           # warms and seals the plant's kernels
    assert all(k.sealed for k in jit.registered(('plant',)))
    x32 = np.zeros(13, dtype=np.float32)
    with jit.compilations() as compiled, pytest.raises(TypeError):
        plant_steps(1, 0, 10_000_000, x32, plant.thrusters.state, plant.servos.state,
                    plant.current.state, plant._cfg, plant._ext_rows, 0, plant._noise,
                    plant._no_log, plant._work)
    assert compiled == []


def test_every_stack_node_reports_its_backend_and_kernel_warmup(ros: Any) -> None:
    from ros_stack import Probe, report

    from tiltrov_ros.core.names import BACKEND_KEY, KERNEL_WARMUP_KEY
    from tiltrov_ros.stack.inprocess import build_nodes
    from tiltrov_ros.stack.specs import LaunchOptions, stack_specs

    probe = Probe(ros.node('diagnostics_probe'), ['/diagnostics'])
    specs, _, _ = stack_specs(LaunchOptions(scenario='pitch_hold', controller='pid'))
    nodes = [ros.add(node) for node in build_nodes(specs, ros.context)]
    assert len(nodes) == 4
    for node in nodes:
        values = report(ros, probe, node)
        assert values[BACKEND_KEY] == jit.backend(), node.get_name()
        assert float(values[KERNEL_WARMUP_KEY]) == pytest.approx(node.kernel_warmup,
                                                                 rel=1e-5, abs=1e-9)
        if node.kernel_groups and jit.compiled():
            assert all(k.sealed for k in jit.registered(node.kernel_groups))


# -- read-only installs ------------------------------------------------------------------

def _read_only(dirs: list[Path], argv: list[str], env: dict[str, str], cwd: Path
               ) -> subprocess.CompletedProcess[str]:
    """Run ``argv`` in ``cwd`` with ``dirs`` read-only: plain permissions for a normal
    user; for root (whom permissions do not stop) read-only bind mounts in a user
    namespace."""
    if os.geteuid() != 0:
        for d in dirs:
            for path in (d, *d.rglob('*')):
                path.chmod(path.stat().st_mode & ~0o222)
        return run_while_progressing(argv, env=env, cwd=cwd)
    probe = subprocess.run(['unshare', '-rm', 'true'], capture_output=True) \
        if shutil.which('unshare') else None
    if probe is None or probe.returncode != 0:
        pytest.skip('running as root without user namespaces: nothing is read-only for root')
    mounts = ''.join(f'mount --bind "{d}" "{d}"; mount -o remount,bind,ro "{d}"; '
                     for d in dirs)
    return run_while_progressing(['unshare', '-rm', 'sh', '-c',
                                  f'set -e; {mounts}exec "$@"', 'sh', *argv], env=env, cwd=cwd)


def _copy_package(target: Path) -> Path:
    """The package with its shipped files, as an install would lay them out."""
    ignore = shutil.ignore_patterns('__pycache__', '*.pyc')
    shutil.copytree(REPO / 'tiltrov_ros', target / 'tiltrov_ros', ignore=ignore)
    shutil.copytree(REPO / 'config', target / 'config', ignore=ignore)
    shutil.copy(REPO / 'package.xml', target / 'package.xml')
    return target


_REPORT = ('import json, sys\n'
           'from tiltrov_ros.cli import main\n'
           'code = main({argv!r}) if {argv!r} else 0\n'
           'import tiltrov_ros\n'
           'from tiltrov_ros.core import jit\n'
           'print(json.dumps({{"code": code, "file": tiltrov_ros.__file__, '
           '"jit": jit.describe()}}))\n')


@pytest.mark.slow
@needs_numba
def test_a_read_only_install_with_no_writable_home_caches_in_the_temporary_directory(
        tmp_path: Path) -> None:
    """The package read-only and no writable home: the kernels' cache is in the
    temporary directory, and a run works there. The cache is seeded with this
    session's (the same sources share one cache wherever they are installed), so that
    the run loads the kernels rather than compiling them all again; a cold cache is
    the test above's."""
    install = _copy_package(tmp_path / 'install')
    home, tmp, out = tmp_path / 'home', tmp_path / 'tmp', tmp_path / 'out'
    home.mkdir()
    tmp.mkdir()
    warm = Path(jit.describe()['cache_dir'])
    shutil.copytree(warm, tmp / f'tiltrov_ros-numba-{os.getuid()}' / jit.source_key())
    env = _env(PYTHONPATH=str(install), HOME=str(home), TMPDIR=str(tmp))
    code = _REPORT.format(argv=[*SIM, '--out', str(out)])
    result = _read_only([install, home], [sys.executable, '-c', code], env, tmp_path)
    assert result.returncode == 0, result.stderr
    report = _last_json(result.stdout)
    assert report['code'] == 0
    assert report['file'].startswith(str(install))
    cache = Path(report['jit']['cache_dir'])
    assert cache.parent.parent == tmp and cache.parent.name.startswith('tiltrov_ros-numba-')
    assert any(cache.rglob('*.nbi'))                   # the kernels were cached there
    assert not any(install.rglob('*.nbi')) and not any(home.iterdir())
    metrics = json.loads((out / 'metrics.json').read_text())
    assert metrics['run']['backend'] == 'numba'


@needs_numba
def test_a_read_only_install_caches_in_the_users_cache_directory(tmp_path: Path) -> None:
    install = _copy_package(tmp_path / 'install')
    home = tmp_path / 'home'
    home.mkdir()
    env = _env(PYTHONPATH=str(install), HOME=str(home))
    result = _read_only([install], [sys.executable, '-c', _REPORT.format(argv=[])], env,
                        tmp_path)
    assert result.returncode == 0, result.stderr
    report = _last_json(result.stdout)
    assert report['jit']['backend'] == 'numba'
    cache = Path(report['jit']['cache_dir'])
    assert cache.parent == home / '.cache' / 'tiltrov_ros' / 'numba' and cache.is_dir()


# -- the numpy reference -----------------------------------------------------------------

def _sim_without(tmp_path: Path, block_numba: bool, **env: str) -> tuple[Any, dict[str, Any]]:
    out = tmp_path / 'out'
    code = ('import sys\n'
            + ("sys.modules['numba'] = None  # import numba raises ImportError\n"
               if block_numba else '')
            + 'from tiltrov_ros.cli import main\n'
            + f'code = main({[*SIM, "--out", str(out)]!r})\n'
            + "print('numba imported' if sys.modules.get('numba') else 'numba not imported')\n"
            + 'sys.exit(code)\n')
    result = _python(code, _env(**env))
    metrics = json.loads((out / 'metrics.json').read_text()) if result.returncode == 0 else {}
    return result, metrics


def _same_answers(metrics: dict[str, Any]) -> list[str]:
    """Differences from this process's run of the same scenario (whatever its backend)."""
    here = compute_metrics(run_scenario(stack_config('pitch_hold', 'pid'), duration=0.5))
    here = json.loads(json.dumps(here))
    here['run']['backend'] = metrics['run']['backend']
    return metric_differences(metrics, here)


@pytest.mark.slow
def test_without_numba_the_reference_runs_with_one_warning(tmp_path: Path) -> None:
    result, metrics = _sim_without(tmp_path, block_numba=True)
    assert result.returncode == 0, result.stderr
    warnings = [line for line in result.stderr.splitlines() if 'numba' in line]
    assert len(warnings) == 1 and 'numba is not available' in warnings[0]
    assert 'numpy reference' in warnings[0]
    assert metrics['run']['backend'] == 'numpy'
    assert _same_answers(metrics) == []


@pytest.mark.slow
def test_tiltrov_backend_numpy_forces_the_reference_quietly(tmp_path: Path) -> None:
    result, metrics = _sim_without(tmp_path, block_numba=False, TILTROV_BACKEND='numpy')
    assert result.returncode == 0, result.stderr
    assert 'numba' not in result.stderr
    assert result.stdout.strip().splitlines()[-1] == 'numba not imported'
    assert metrics['run']['backend'] == 'numpy'
    assert _same_answers(metrics) == []


def test_tiltrov_backend_numba_without_numba_says_why(tmp_path: Path) -> None:
    result, _ = _sim_without(tmp_path, block_numba=True, TILTROV_BACKEND='numba')
    assert result.returncode != 0
    assert 'TILTROV_BACKEND=numba but the compiled kernels cannot be used' in result.stderr


def test_an_unknown_backend_is_named_and_the_reference_runs() -> None:
    result = _python('from tiltrov_ros.core import jit; print(jit.backend())',
                     _env(TILTROV_BACKEND='fortran'))
    assert result.returncode == 0
    assert result.stdout.strip() == 'numpy'
    assert "TILTROV_BACKEND='fortran' is not one of auto, numba, numpy" in result.stderr


def test_tiltrov_warmup_names_the_backend_the_cache_and_each_group() -> None:
    result = run_while_progressing([sys.executable, '-m', 'tiltrov_ros.cli', 'warmup'],
                                   env=_env(), cwd=REPO)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    if jit.compiled():
        assert lines[0].startswith('backend: numba') and lines[1].startswith('cache:')
        for group in jit.GROUPS:
            assert any(line.split()[0] == group for line in lines[2:])
    numpy = run_while_progressing([sys.executable, '-m', 'tiltrov_ros.cli', 'warmup'],
                                  cwd=REPO, env=_env(TILTROV_BACKEND='numpy'))
    assert numpy.returncode == 0
    assert numpy.stdout.splitlines() == ['backend: numpy (TILTROV_BACKEND=numpy)',
                                         'nothing to compile: the numpy reference runs']


def test_the_cache_is_keyed_by_the_sources_and_shared_by_their_installs(
        tmp_path: Path) -> None:
    """Two installs of the same sources in two places share one cache: the second loads
    what the first compiled (before, numba keyed it by the absolute path, and a colcon
    workspace compiled everything again in its nodes' constructors, 74 s once). An edit
    anywhere in the core (here a kernel that others call) gives another key: numba
    itself checks a cached kernel against its own file only, and once ran an edited
    callee's old code inside a cached caller."""
    home = tmp_path / 'home'
    home.mkdir()
    env = _env(HOME=str(home))
    code = ('import json\nfrom tiltrov_ros.core import jit\n'
            'with jit.compilations() as done:\n'
            '    jit.warmup(["control"])\n'
            'print(json.dumps([jit.backend(), jit.describe()["cache_dir"], len(done)]))\n')

    def warm(install: Path) -> tuple[str, Path, int]:
        result = run_while_progressing([sys.executable, '-c', code],
                                       env=dict(env, PYTHONPATH=str(install)), cwd=tmp_path)
        assert result.returncode == 0, result.stderr
        name, directory, compiled = _last_json(result.stdout)
        return name, Path(directory or '.'), compiled

    first, second = _copy_package(tmp_path / 'a'), _copy_package(tmp_path / 'b')
    name, cache, compiled = warm(first)
    if name != 'numba':
        pytest.skip('numba is not installed: no kernel cache')
    assert cache.parent == home / '.cache' / 'tiltrov_ros' / 'numba' and compiled > 0
    assert warm(second) == (name, cache, 0)           # loaded, not compiled again
    callee = second / 'tiltrov_ros' / 'core' / 'kinematics.py'
    callee.write_text(callee.read_text() + '\n# edited\n')
    _, edited, compiled = warm(second)
    assert edited != cache and edited.parent == cache.parent and compiled > 0
    assert warm(first) == (name, cache, 0)            # the first install's cache was kept
