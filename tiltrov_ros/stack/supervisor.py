"""The process supervisor of ``tiltrov launch``: every node as its own process.

Each node runs as ``ros2 launch`` would start it: the node's executable with
``--ros-args --params-file config/robot.yaml --params-file config/<node>.yaml
--params-file <overrides>``. Output lines are prefixed with the node's name.
The run ends when the plant reaches its duration of sim time: the plant
(``exit_at_end``) exits 0 once its last messages are acknowledged, and the
supervisor stops the other nodes (SIGINT, then SIGTERM, then SIGKILL) and
returns 0. A node that exits before that stops the launch: the others are
stopped and it returns 1 naming it. Ctrl-C stops every node cleanly (130).

``respawn`` (controller, allocator or reference) starts a node again, with the
same arguments, when its process dies mid-run: the plant keeps its state,
re-publishes the tick it waits at (lockstep) and the loop resumes with the new
process (docs/reliability.md).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
import contextlib
from dataclasses import dataclass
import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import threading
import time
from typing import IO, Any

from tiltrov_ros import paths
from tiltrov_ros.core.atomic import replace_text
from tiltrov_ros.core.names import (
    PLANT,
    RECORDER,
    STANDBY_ENV,
    standby_name,
)

from .specs import NodeSpec

EXIT_OK = 0
EXIT_FAILED = 1
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130

#: s (wall) a node gets to exit after SIGINT, then after SIGTERM, before SIGKILL; the
#: first above the time a stopping node waits for its readers (nodes/base.DELIVERY_WAIT).
STOP_TIMEOUTS = (13.0, 3.0)
#: s (wall) the recorder gets to close its bag after SIGINT.
RECORDER_STOP_TIMEOUT = 20.0
POLL = 0.05

EXIT_OK = 0
EXIT_FAILED = 1
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130


# --------------------------------------------------------------------------- output


class Output:
    """Prefixed, line-atomic output of several processes."""

    def __init__(self, stream: IO[str]) -> None:
        self._stream = stream
        self._lock = threading.Lock()
        self.width = 0

    def line(self, name: str, text: str) -> None:
        with self._lock:
            self._stream.write(f'[{name}]{" " * (self.width - len(name))} {text}\n')
            self._stream.flush()

    def pump(self, name: str, pipe: IO[bytes]) -> None:
        for raw in iter(pipe.readline, b''):
            self.line(name, raw.decode('utf-8', 'replace').rstrip('\n'))
        pipe.close()


# --------------------------------------------------------------------------- processes


def executable(spec: NodeSpec) -> list[str]:
    """argv[0:] that runs ``spec``'s node: its installed executable
    (:func:`tiltrov_ros.paths.executable`), else ``python -m`` its module."""
    found = paths.executable(spec.name)
    return [str(found)] if found is not None else [sys.executable, '-m', spec.module]


def _die_with_parent() -> None:  # pragma: no cover - runs in the child
    """Linux: the child gets SIGTERM if the launcher dies without stopping it."""
    with contextlib.suppress(Exception):
        import ctypes
        ctypes.CDLL('libc.so.6', use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


@dataclass
class _Child:
    spec: NodeSpec
    process: subprocess.Popen[bytes]
    pump: threading.Thread


class _Stop(Exception):
    """Raised by the signal handler to leave the wait loop."""


def _stop_children(children: Sequence[_Child], out: Output,
                   hurry: threading.Event | None = None) -> None:
    """SIGINT the stack nodes, then the recorder; escalate to SIGTERM and SIGKILL.

    ``hurry`` set (a second Ctrl-C) cuts every wait short.
    """
    stack = [c for c in children if c.spec.name != RECORDER]
    recorder = [c for c in children if c.spec.name == RECORDER]
    for group, first_timeout in ((stack, STOP_TIMEOUTS[0]),
                                 (recorder, RECORDER_STOP_TIMEOUT)):
        for sig, timeout in ((signal.SIGINT, first_timeout), (signal.SIGTERM, STOP_TIMEOUTS[1]),
                             (signal.SIGKILL, STOP_TIMEOUTS[1])):
            alive = [c for c in group if c.process.poll() is None]
            if not alive:
                break
            if sig != signal.SIGINT:
                out.line('launch', f'sending {sig.name} to '
                                   f'{", ".join(c.spec.name for c in alive)}')
            for child in alive:
                with contextlib.suppress(ProcessLookupError):
                    child.process.send_signal(sig)
            deadline = time.monotonic() + timeout
            while (time.monotonic() < deadline and not (hurry and hurry.is_set())
                   and any(c.process.poll() is None for c in alive)):
                time.sleep(POLL)
    for child in children:
        child.pump.join(timeout=2.0)


class Monitor:
    """Hooks of :func:`run_processes` (``tiltrov soak`` measures through them)."""

    def poll(self, pids: Mapping[str, int]) -> None:
        """Called about every POLL s with each live node's pid."""

    def finished(self, pids: Mapping[str, int]) -> None:
        """Called once the plant has ended the run, before the others are stopped."""


class StatusFile:
    """``tiltrov launch --status-file FILE``: what the launch is doing, as JSON,
    replaced atomically at each change, so a script (or a test) waits on it
    instead of reading the output::

        {"state": "running", "exit_code": null,
         "nodes": {"plant_simulator": {"pid": 4242, "starts": 1, "running": true}, ...}}

    ``state``: ``starting`` (processes being started), ``running`` (every node
    started), ``stopping``, ``ended`` (``exit_code`` set). No file when ``path``
    is None.
    """

    def __init__(self, path: Path | None) -> None:
        self.path = path

    def write(self, state: str, nodes: Mapping[str, Mapping[str, Any]],
              exit_code: int | None = None) -> None:
        if self.path is None:
            return
        document = {'state': state, 'exit_code': exit_code, 'nodes': dict(nodes)}
        replace_text(self.path, json.dumps(document, indent=1) + '\n')


class _Supervisor:
    """The node processes of one launch (see :func:`run_processes`)."""

    def __init__(self, namespace: str, out: Output, workdir: Path, env: Mapping[str, str],
                 respawn: Sequence[str], monitor: Monitor | None, status: StatusFile) -> None:
        self.namespace = namespace
        self.out = out
        self.workdir = workdir
        self.env = dict(env)
        self.respawn = respawn
        self.monitor = monitor
        self.status = status
        self.children: list[_Child] = []
        #: node name -> its standby process (``--respawn``: nodes/handoff.py)
        self.standbys: dict[str, _Child] = {}
        self.starts: dict[str, int] = {}

    def start(self, spec: NodeSpec, *, standby: bool = False) -> _Child:
        """Start ``spec``'s node, or (``standby``) its standby: the same executable and
        arguments, which loads its kernels, keeps the node's handoff and takes over on
        SIGUSR1."""
        overrides = spec.write_overrides(self.workdir, self.namespace, standby=standby)
        argv = executable(spec) + spec.ros_args(overrides, self.namespace)
        label = standby_name(spec.name) if standby else spec.name
        env = dict(self.env, **({STANDBY_ENV: '1'} if standby else {}))
        process = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                   stderr=subprocess.STDOUT, env=env,
                                   start_new_session=True, preexec_fn=_die_with_parent)
        pump = threading.Thread(target=self.out.pump, args=(label, process.stdout),
                                daemon=True)
        pump.start()
        self.starts[label] = self.starts.get(label, 0) + 1
        self.out.line('launch', f'started {label} (pid {process.pid})')
        return _Child(spec, process, pump)

    def respawn_node(self, i: int, rc: int) -> None:
        """The node of ``children[i]`` died: its standby takes over (SIGUSR1) and a new
        standby starts; without a live standby, the node starts again."""
        child = self.children[i]
        name = child.spec.name
        child.pump.join(timeout=2.0)
        standby = self.standbys.pop(name, None)
        if standby is not None and standby.process.poll() is None:
            self.out.line('launch', f'{name} died (exit code {rc}); its standby (pid '
                                    f'{standby.process.pid}) takes over (--respawn)')
            standby.process.send_signal(signal.SIGUSR1)
            self.children[i] = standby
            self.starts[name] += 1
        else:
            self.out.line('launch', f'{name} died (exit code {rc}); starting it again '
                                    '(--respawn)')
            self.children[i] = self.start(child.spec)
        self.standbys[name] = self.start(child.spec, standby=True)
        self.report('running')

    def every_process(self) -> list[_Child]:
        return [*self.children, *self.standbys.values()]

    def report(self, state: str, code: int | None = None) -> None:
        nodes = {c.spec.name: {'pid': c.process.pid, 'starts': self.starts[c.spec.name],
                               'running': c.process.poll() is None} for c in self.children}
        nodes.update({standby_name(name): {'pid': c.process.pid,
                                           'starts': self.starts[standby_name(name)],
                                           'running': c.process.poll() is None}
                      for name, c in self.standbys.items()})
        self.status.write(state, nodes, code)

    def watch(self, summary: str, started: float) -> int:
        """Until the plant ends the run (EXIT_OK) or a node not respawned dies (EXIT_FAILED);
        ``started``: monotonic time the launch began."""
        while True:
            for i, child in enumerate(self.children):
                rc = child.process.poll()
                if rc is None:
                    continue
                name = child.spec.name
                if name == PLANT and rc == 0:
                    wall = time.monotonic() - started
                    if self.monitor is not None:
                        self.monitor.finished(_pids(self.children))
                    self.out.line('launch', f'{summary} done in {wall:.2f} s wall; stopping '
                                            'the other nodes')
                    return EXIT_OK
                if name in self.respawn:
                    self.respawn_node(i, rc)
                    continue
                self.out.line('launch', f'{name} died (exit code {rc}); stopping the other '
                                        'nodes')
                return EXIT_FAILED
            for name, standby in self.standbys.items():
                rc = standby.process.poll()
                if rc is not None:      # the run waits for it (a node of its handshake)
                    self.out.line('launch', f'{standby_name(name)} died (exit code {rc}); '
                                            'stopping the other nodes')
                    return EXIT_FAILED
            if self.monitor is not None:
                self.monitor.poll(_pids(self.children))
            time.sleep(POLL)


def run_processes(specs: Sequence[NodeSpec], namespace: str, out: Output,
                  summary: str, workdir: Path, extra_env: Mapping[str, str] | None = None,
                  *, respawn: Sequence[str] = (), monitor: Monitor | None = None,
                  status_file: Path | None = None) -> int:
    """Start every node as a process; return when the run ends or a node dies.

    A node named in ``respawn`` that dies is started again instead. The others are
    stopped once the plant has ended the run (each publishes its final report and
    waits until the recorder has it: nodes/executors.finish). ``status_file``: see
    :class:`StatusFile`.
    """
    env = dict(os.environ, PYTHONUNBUFFERED='1', RCUTILS_LOGGING_BUFFERED_STREAM='1',
               **(extra_env or {}))
    out.width = max(len(s.name) for s in specs)
    supervisor = _Supervisor(namespace, out, workdir, env, respawn, monitor,
                             StatusFile(status_file))
    previous = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    stopping = threading.Event()
    hurry = threading.Event()

    def on_signal(signum: int, frame: Any) -> None:
        if stopping.is_set():       # already stopping: a second Ctrl-C hurries it
            hurry.set()
            return
        stopping.set()
        raise _Stop(signal.Signals(signum).name)

    started = time.monotonic()
    code = EXIT_OK
    try:
        for sig in previous:
            signal.signal(sig, on_signal)
        supervisor.report('starting')
        for spec in specs:
            supervisor.children.append(supervisor.start(spec))
            supervisor.report('starting')
        for spec in specs:
            if spec.name in respawn:
                supervisor.standbys[spec.name] = supervisor.start(spec, standby=True)
        supervisor.report('running')
        code = supervisor.watch(summary, started)
    except _Stop as stop:
        out.line('launch', f'{stop.args[0]}: stopping every node')
        code = EXIT_INTERRUPTED
    finally:
        stopping.set()              # from here on a signal only hurries the stop
        supervisor.report('stopping')
        try:
            _stop_children(supervisor.every_process(), out, hurry)
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
        if code == EXIT_FAILED:
            dead = [c.spec.name for c in supervisor.children
                    if c.process.returncode not in (0, None, -signal.SIGINT)]
            dead += [standby_name(name) for name, c in supervisor.standbys.items()
                     if c.process.returncode not in (0, None, -signal.SIGINT)]
            print(f'tiltrov launch: failed: {", ".join(dead) or "a node"} died', file=sys.stderr)
        recorder = next((c for c in supervisor.children if c.spec.name == RECORDER), None)
        if code == EXIT_OK and recorder is not None and recorder.process.returncode != 0:
            print(f'tiltrov launch: failed: bag_recorder exit code '
                  f'{recorder.process.returncode} (it lost data)', file=sys.stderr)
            code = EXIT_FAILED
        supervisor.report('ended', code)
    return code


def _pids(children: Sequence[_Child]) -> dict[str, int]:
    return {c.spec.name: c.process.pid for c in children if c.process.poll() is None}
