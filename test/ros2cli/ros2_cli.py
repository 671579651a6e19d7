"""Helpers of the tests with the real ``ros2`` command line (see conftest.py)."""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path
import re
import shlex
import signal
import subprocess
import sys
from typing import Any

from harness import TreeProgress, wait_while_progressing
from workspace import Workspace

#: What the tests need of the command line: ros2cli's verbs and ros2 launch.
CLI_MODULES = ('ros2cli', 'ros2run', 'ros2param', 'ros2topic', 'ros2pkg', 'ros2launch',
               'launch_ros')


def missing_cli() -> str | None:
    """Why the real ros2 command line cannot run here, or None."""
    absent = [m for m in CLI_MODULES if importlib.util.find_spec(m) is None]
    if absent:
        return (f'the ros2 command line is not installed ({", ".join(absent)} not '
                f'importable): `make ros2-cli` adds it from TILTROV_ROS2_CLI, or run '
                f'in a ROS 2 Jazzy install')
    return None

#: A line of Fast DDS's own log (``2026-01-01 00:00:00.000 [RTPS_TRANSPORT_SHM Error] ...``,
#: colored), which it prints on stdout: e.g. a shared-memory port another process holds.
_DDS_LOG = re.compile(r'^\d{4}-\d\d-\d\d \d\d:\d\d:\d\d\.\d+ \[\w+ (Error|Warning|Info)\]')
_ANSI = re.compile(r'\x1b\[[0-9;]*m')


class Ran(subprocess.CompletedProcess[str]):
    """A finished command, with Fast DDS's own log lines apart (``dds_log``)."""

    dds_log = ''


def without_dds_log(result: subprocess.CompletedProcess[str]) -> Ran:
    """``result`` without Fast DDS's log lines on stdout and stderr (kept in
    ``dds_log``): the command's own output is what the user reads and what the tests
    compare. Those lines say what the machine's other DDS processes do to this one (a
    shared-memory port another process holds), whatever the command."""
    streams, moved = [], []
    for text in (result.stdout, result.stderr):
        kept = []
        for line in (text or '').splitlines(keepends=True):
            (moved if _DDS_LOG.match(_ANSI.sub('', line)) else kept).append(line)
        streams.append(''.join(kept))
    ran = Ran(result.args, result.returncode, streams[0], streams[1])
    ran.dds_log = ''.join(moved)
    return ran


#: ros2 verbs that look at the graph (through the daemon, unless --no-daemon).
GRAPH_VERBS = ('node', 'param', 'topic', 'service')
#: ros2 param verbs that wait (--timeout) until the node is discovered.
NODE_WAITS = ('get', 'set', 'describe', 'dump', 'delete', 'load')
#: A graph command that hangs is run again, up to this many times in all: a service
#: reply can be lost when the request goes out before the node's reply writer has
#: matched the command's reader (seen once in about ten runs: ``ros2 param dump``
#: waiting for ever). The commands are queries or idempotent sets.
ATTEMPTS = 3
#: s: how long one attempt may take.
ATTEMPT_TIMEOUT = 45.0


class Ros2:
    """Runs ``ros2 ...`` (and other commands) in the workspace's environment."""

    def __init__(self, workspace: Workspace) -> None:
        self.workspace = workspace
        self.env = dict(workspace.env, PYTHONUNBUFFERED='1')
        exe = Path(sys.executable).with_name('ros2')
        self.exe = str(exe) if exe.exists() else 'ros2'
        self.processes: list[subprocess.Popen[str]] = []

    def argv(self, argv: list[str]) -> list[str]:
        return [self.exe, *argv[1:]] if argv and argv[0] == 'ros2' else argv

    def command(self, args: tuple[str, ...]) -> list[str]:
        """argv of ``ros2 args...``. The graph verbs run without the daemon (none is
        left running; discovery by the command itself); ``ros2 param`` waits up to 20 s
        for the node (discovery without multicast can take a few seconds)."""
        if args[:1] and args[0] in GRAPH_VERBS and '--no-daemon' not in args:
            args = (*args[:2], '--no-daemon', *args[2:])
        if args[:1] == ('param',) and args[1] in NODE_WAITS and '--timeout' not in args:
            args = (*args[:2], '--timeout', '20', *args[2:])   # until the node is found
        return self.argv(['ros2', *args])

    def run(self, *args: str, cwd: Path | None = None,
            timeout: float = ATTEMPT_TIMEOUT) -> subprocess.CompletedProcess[str]:
        """``ros2 args...`` to its end: its exit code and output (a graph command that
        hangs is run again, :data:`ATTEMPTS`)."""
        attempts = ATTEMPTS if args[:1] and args[0] in GRAPH_VERBS else 1
        for attempt in range(attempts):
            try:
                return without_dds_log(subprocess.run(
                    self.command(args), cwd=cwd or self.workspace.root, env=self.env,
                    capture_output=True, text=True, timeout=timeout))
            except subprocess.TimeoutExpired:
                if attempt == attempts - 1:
                    raise
        raise AssertionError('unreachable')

    def run_all(self, commands: list[tuple[str, ...]],
                timeout: float = ATTEMPT_TIMEOUT) -> list[subprocess.CompletedProcess[str]]:
        """Several ``ros2`` commands to their ends, results in order. They run in rounds
        in which each ``ros2 param`` command talks to a different node (each waits for
        discovery on its own, so a round takes the time of one command); two requests
        to one node are never in flight at once."""
        rounds: list[list[int]] = []
        for i, args in enumerate(commands):
            target = args[2] if args[:1] == ('param',) and len(args) > 2 else None
            for batch in rounds:
                if target is None or target not in {commands[j][2] for j in batch
                                                    if commands[j][:1] == ('param',)}:
                    batch.append(i)
                    break
            else:
                rounds.append([i])
        results: dict[int, subprocess.CompletedProcess[str]] = {}
        for batch in rounds:
            procs = {i: subprocess.Popen(self.command(commands[i]), cwd=self.workspace.root,
                                         env=self.env, stdout=subprocess.PIPE,
                                         stderr=subprocess.PIPE, text=True) for i in batch}
            try:
                for i, proc in procs.items():
                    try:
                        out, err = proc.communicate(timeout=timeout)
                    except subprocess.TimeoutExpired:   # hung: again, alone (run)
                        proc.kill()
                        proc.wait(timeout=10)
                        results[i] = self.run(*commands[i], timeout=timeout)
                        continue
                    results[i] = without_dds_log(subprocess.CompletedProcess(
                        proc.args, proc.returncode, out, err))
            finally:
                for proc in procs.values():
                    if proc.poll() is None:
                        proc.kill()
                        proc.wait(timeout=10)
        return [results[i] for i in range(len(commands))]

    def run_to_end(self, *args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
        """``ros2 args...`` that runs a while (a launch, a whole run): to its end, however
        slowly a loaded machine runs it (the wait gives up only on a hang,
        :func:`wait_while_progressing`); its exit code and output (stdout and stderr
        together)."""
        log = cwd / f'ros2-{len(self.processes)}.log'
        proc = self.start(['ros2', *args], cwd, log)
        code = wait_while_progressing(proc)
        return subprocess.CompletedProcess(proc.args, code, log.read_text(), '')

    def start(self, argv: list[str], cwd: Path, log: Path) -> subprocess.Popen[str]:
        """``argv`` in a session of its own (a terminal's foreground job), its output
        (stdout and stderr) into ``log``."""
        stream = log.open('w')
        proc = subprocess.Popen(self.argv(argv), cwd=cwd, env=self.env, stdout=stream,
                                stderr=subprocess.STDOUT, text=True, start_new_session=True)
        stream.close()
        self.processes.append(proc)
        return proc

    def cleanup(self) -> None:
        """Whatever a failed test left running (each session's processes)."""
        for proc in self.processes:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(timeout=10)


def ctrl_c(proc: subprocess.Popen[str]) -> int:
    """SIGINT to ``proc``'s session, as Ctrl-C in its terminal sends it to every
    process of the foreground job; its exit code, once it has ended (however slowly a
    loaded machine stops it: the wait gives up only on a hang, :func:`wait_while_progressing`)."""
    os.killpg(proc.pid, signal.SIGINT)
    return wait_while_progressing(proc)


def wait_nodes(ros: Any, names: set[str], procs: list[subprocess.Popen[str]]) -> None:
    """Spin a probe until the nodes ``names`` (full names) are in the graph, failing
    at once when one of ``procs`` has ended, and on a hang: nothing new in the graph
    while ``procs`` used no CPU for a while (a loaded machine starts them slowly: one
    node took over 60 s to appear beside two busy loops and another test's stack)."""
    probe = ros.node('cli_probe')

    def seen() -> set[str]:
        return {f'{ns.rstrip("/")}/{name}'
                for name, ns in probe.get_node_names_and_namespaces()}

    def ended() -> list[Any]:
        return [p.args for p in procs if p.poll() is not None]

    cpu = TreeProgress(*(p.pid for p in procs))
    ros.spin_while_progressing(lambda: names <= seen() or bool(ended()),
                               lambda: (frozenset(seen()), cpu()))
    assert names <= seen() and not ended(), (ended(), names - seen())


def doc_commands(path: Path, start: str) -> list[list[str]]:
    """The command lines beginning with ``start`` in the shell blocks of the document
    ``path`` (continuation lines joined, comments dropped), as argv lists."""
    commands: list[list[str]] = []
    for block in re.findall(r'```(?:bash|console)\n(.*?)```', path.read_text(), re.S):
        for line in block.replace('\\\n', ' ').splitlines():
            line = line.removeprefix('$ ')
            if line.startswith(start):
                commands.append(shlex.split(line, comments=True))
    return commands


def overrides(argv: list[str]) -> dict[str, str]:
    """The ``-p NAME:=VALUE`` of a command line."""
    return dict(argv[i + 1].split(':=', 1) for i, arg in enumerate(argv[:-1]) if arg == '-p')
