"""The run's handshake: every node of a run says, on the ``handshake`` topic, when each of
its endpoints has matched the run's other nodes, seen from its own side; the plant starts
(and resumes a tick after a restart) only when every node of the run says so.

Why both sides: DDS matches a writer and a reader separately. A volatile reader drops
what a writer sent before the reader had matched it, and a writer does not send to a
reader it has not matched: a message is only safe once *both* ends have matched. Each
node can only see its own end (its writers' and readers' matched counts), so each one
reports its own, and the plant collects the reports (docs/nodes.md, "The handshake").

The launchers give every node the run's node names (``run_nodes``, run_info's
``nodes``). A node of a run:

* publishes its state (``diagnostic_msgs/DiagnosticStatus``, reliable, transient local:
  a node started later still gets every other node's latest one): its name, its
  instance (a new one each time the process starts), the topics it publishes and
  subscribes, ``ready`` and what it waits for;
* is *ready* when it holds the state of every run node and, for each of its own
  endpoints on a topic T, (a) every run node that has the opposite endpoint on T is in
  its graph on T, and (b) its endpoint has matched at least as many endpoints as its
  graph shows on T with a compatible type and QoS (the graph and the match come from
  the same discovery data, so a peer it sees and has not matched is still on its way);
  ready, it names the instances it is ready with (``peers``);
* re-evaluates when a state comes (a restarted node is a new instance: every node must
  match it again) and, while not ready, every :data:`POLL` wall seconds: a poll only
  sets how soon a met condition is noticed, never whether it is met.

The run is ready (:meth:`Handshake.run_ready`) when every run node is ready with the same
instances, the latest of each name. Nodes outside the run (robot_state_publisher, RViz, a
user's probe) are never waited for; a node given no run nodes has no handshake at all.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
import os
import time
from typing import TYPE_CHECKING, Any

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rclpy.clock import Clock
from rclpy.clock_type import ClockType
from rclpy.node import Node

from tiltrov_ros.bag.qos import unmatched
from tiltrov_ros.core.names import HANDSHAKE, join_namespace

from .qos import HANDSHAKE_READER_QOS, LATCHED_QOS

if TYPE_CHECKING:
    from .base import TiltrovNode

#: s (wall): how often a node that is not ready looks at its endpoints again.
POLL = 0.01
#: Topics no handshake covers: the handshake itself (transient local: its order does not
#: matter) and rclpy's own.
UNCOVERED = frozenset({'/parameter_events', '/rosout'})
OK, WARN = 0, 1
#: Values a node adds to its state: the plant its mode, its pacing window (s of sim time,
#: when the recorder paces it) and the end of the run (ns of sim time: the state there is
#: answered by no node); the recorder the node instances whose final report and every
#: message it counts are in the bag (``name=instance`` words).
MODE_KEY = 'mode'
WINDOW_KEY = 'recorder_window'
END_KEY = 'end_ns'
RECORDED_KEY = 'recorded'


def new_instance() -> str:
    """An instance id: the start time (ns, so later starts sort later) and the pid."""
    return f'{time.time_ns()}.{os.getpid()}'


def _instance_time(instance: str) -> int:
    head = instance.partition('.')[0]
    return int(head) if head.isdigit() else -1


@dataclass(frozen=True)
class NodeState:
    """One node's handshake state, as published."""

    name: str                                  # node name (the run's namespace)
    instance: str
    ready: bool
    publishes: frozenset[tuple[str, str]]      # (resolved topic name, endpoint gid)
    subscribes: frozenset[tuple[str, str]]
    peers: tuple[tuple[str, str], ...] = ()    # (name, instance) it is ready with
    waiting_for: str = ''
    extra: dict[str, str] = field(default_factory=dict)

    def to_message(self, full_name: str) -> DiagnosticStatus:
        values = {'instance': self.instance, 'ready': str(self.ready).lower(),
                  'publishes': _endpoints_text(self.publishes),
                  'subscribes': _endpoints_text(self.subscribes),
                  'peers': ' '.join(f'{n}={i}' for n, i in self.peers),
                  'waiting_for': self.waiting_for, **self.extra}
        return DiagnosticStatus(
            level=bytes([OK if self.ready else WARN]), name=full_name,
            message='ready' if self.ready else f'waiting for {self.waiting_for}',
            hardware_id=self.instance,
            values=[KeyValue(key=k, value=v) for k, v in values.items()])

    @classmethod
    def from_message(cls, msg: DiagnosticStatus) -> NodeState:
        values = {kv.key: kv.value for kv in msg.values}
        peers = tuple(tuple(p.split('=', 1)) for p in values.pop('peers', '').split()
                      if '=' in p)
        known = ('instance', 'ready', 'publishes', 'subscribes', 'waiting_for')
        return cls(name=msg.name.rsplit('/', 1)[-1], instance=values.get('instance', ''),
                   ready=values.get('ready') == 'true',
                   publishes=_endpoints_of(values.get('publishes', '')),
                   subscribes=_endpoints_of(values.get('subscribes', '')),
                   peers=peers,  # type: ignore[arg-type]
                   waiting_for=values.get('waiting_for', ''),
                   extra={k: v for k, v in values.items() if k not in known})


def _endpoints_text(endpoints: Iterable[tuple[str, str]]) -> str:
    return ' '.join(f'{topic}|{gid}' for topic, gid in sorted(endpoints))


def _endpoints_of(text: str) -> frozenset[tuple[str, str]]:
    return frozenset(tuple(item.split('|', 1)) for item in text.split()  # type: ignore[misc]
                     if '|' in item)


def _gid(info: Any) -> str:
    return bytes(info.endpoint_gid).hex()


#: Hex digits of a gid's GUID prefix (12 bytes): the participant the endpoint belongs to.
_PREFIX = 24
#: Attribute of an rclpy context: the GUID prefix of its DDS participant, once known.
_PARTICIPANT_ATTR = '_tiltrov_participant'


def _own_participant(node: Any, topic: str) -> str | None:
    """The GUID prefix of ``node``'s DDS participant, or None while nothing tells.

    Read from its endpoints on ``topic`` when they all have one prefix (a node's own
    endpoints are in its graph at once), and kept on the context for a node built later
    in the same participant: the node a standby builds at a takeover, whose graph may
    still hold its killed predecessor's endpoints under the same name (until the dead
    participant's lease ends). The kept prefix is used only while it is among the
    node's: rmw ends a context's participant with its last node and makes a new one
    for the next."""
    prefixes = {_gid(i)[:_PREFIX] for i in node.get_publishers_info_by_topic(topic)
                if i.node_name == node.get_name() and i.node_namespace == node.get_namespace()}
    known = getattr(node.context, _PARTICIPANT_ATTR, None)
    if known in prefixes:
        return str(known)
    if len(prefixes) != 1:
        return None
    prefix = prefixes.pop()
    setattr(node.context, _PARTICIPANT_ATTR, prefix)
    return prefix


class Handshake:
    """One node's part of the run's handshake (see the module docstring).

    ``on_change`` is called after every change of what this node knows (its own state or
    another node's); the plant decides there whether the run is ready. Any rclpy node
    may join a run this way (a tool that must miss nothing of it, named to the launcher
    with ``tiltrov launch --join NAME``): build it with the run's node names once its
    endpoints exist, and call :meth:`start`; the run starts once it is ready too.
    """

    def __init__(self, node: TiltrovNode | Node, run_nodes: Sequence[str],
                 on_change: Callable[[], None] | None = None) -> None:
        self.node = node
        self.name = node.get_name()
        self.namespace = node.get_namespace()
        self.run_nodes = tuple(dict.fromkeys(run_nodes))
        self.instance = new_instance()
        self.on_change = on_change
        self.states: dict[str, NodeState] = {}
        self.ready = not self.run_nodes
        self.waiting_for = '' if self.ready else 'start'
        #: Values of this node's state besides the handshake's own (the plant's pacing).
        self.extra: dict[str, str] = {}
        #: Each time the run became ready with a new set of instances: +1.
        self.generation = 0
        self._ready_with: dict[str, str] | None = None
        self._published: NodeState | None = None
        #: Instances of other run nodes this node has sent its state to once more.
        self._answered: set[str] = set()
        self._pub: Any = None
        self._timer: Any = None
        #: GUID prefix of this node's DDS participant (:func:`_own_participant`).
        self.participant: str | None = None
        self.started = False

    @property
    def active(self) -> bool:
        """The node is part of a run (it was given run nodes)."""
        return bool(self.run_nodes)

    def start(self) -> None:
        """Join the handshake (call once every endpoint of the node exists)."""
        if not self.active or self.started:
            return
        self.started = True
        node = self.node
        self._pub = node.create_publisher(DiagnosticStatus, HANDSHAKE, LATCHED_QOS)
        self.participant = _own_participant(node, self._resolved(HANDSHAKE))
        node.create_subscription(DiagnosticStatus, HANDSHAKE, self._on_state,
                                 HANDSHAKE_READER_QOS)
        self._timer = node.create_timer(POLL, self._poll,
                                        clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.evaluate()

    # -- what the node is --------------------------------------------------------------

    def _own_endpoints(self) -> tuple[list[Any], list[Any]]:
        """This node's covered publishers and subscriptions."""
        node = self.node
        pubs = [p for p in node.publishers
                if p is not self._pub and p.topic_name not in UNCOVERED]
        subs = [s for s in node.subscriptions
                if s.topic_name != self._resolved(HANDSHAKE) and s.topic_name not in UNCOVERED]
        return pubs, subs

    def _resolved(self, topic: str) -> str:
        return join_namespace(self.namespace, topic)

    def _gids(self, endpoints: Iterable[Any], *, publishers: bool
              ) -> frozenset[tuple[str, str]]:
        """(topic, gid) of this node's ``endpoints`` (from its own graph, where they are
        at once; those of its participant only: a node built by its standby may still see
        its killed predecessor's endpoints under its own name)."""
        node = self.node
        found = set()
        for topic in {e.topic_name for e in endpoints}:
            infos = (node.get_publishers_info_by_topic(topic) if publishers
                     else node.get_subscriptions_info_by_topic(topic))
            found.update((topic, _gid(i)) for i in infos
                         if i.node_name == self.name and i.node_namespace == self.namespace
                         and _gid(i).startswith(self.participant or ''))
        return frozenset(found)

    def own_state(self) -> NodeState:
        pubs, subs = self._own_endpoints()
        return NodeState(self.name, self.instance, self.ready,
                         self._gids(pubs, publishers=True),
                         self._gids(subs, publishers=False),
                         tuple(sorted(self._ready_with.items())) if self._ready_with else (),
                         self.waiting_for, dict(self.extra))

    def instances(self) -> dict[str, str]:
        """Run node -> its latest instance known here (this node's own included)."""
        return {n: self.states[n].instance for n in self.run_nodes if n in self.states}

    # -- the evaluation ----------------------------------------------------------------

    def _on_state(self, msg: DiagnosticStatus) -> None:
        try:
            state = NodeState.from_message(msg)
        except (ValueError, TypeError):
            return
        if state.name not in self.run_nodes or state.name == self.name:
            return
        if not msg.name.startswith(self.namespace.rstrip('/') + '/'):
            return          # a node of another run's namespace with the same name
        known = self.states.get(state.name)
        if known is not None and _instance_time(state.instance) < _instance_time(known.instance):
            return          # an older process of that node, reported late
        self.states[state.name] = state
        if not state.ready and state.instance not in self._answered:
            self._answer(state.instance)
        if os.environ.get('TILTROV_HANDSHAKE_DEBUG') and known is None:
            self.node.get_logger().info(f'handshake: state of {state.name}; graph: '
                                        f'{sorted(self.node.get_node_names())}')
        if known is None or known.instance != state.instance or (
                known.publishes, known.subscribes) != (state.publishes, state.subscribes):
            self.evaluate()
        else:
            self._changed()

    def _answer(self, instance: str) -> None:
        """Send this node's state once more, live, for a new instance of a run node that
        is not ready: a reader made in a participant the others had long known once got
        none of their kept (transient local) states and waited for ever, while states
        published after its match reached it."""
        self._answered.add(instance)
        if self._published is not None:
            self._pub.publish(self._published.to_message(self.node.get_fully_qualified_name()))

    def _poll(self) -> None:
        if not self.ready or self._endpoints_changed():
            self.evaluate()

    def _endpoints_changed(self) -> bool:
        published = self._published
        if published is None:
            return True
        pubs, subs = self._own_endpoints()
        return ({p.topic_name for p in pubs} != {t for t, _ in published.publishes}
                or {s.topic_name for s in subs} != {t for t, _ in published.subscribes})

    def evaluate(self) -> None:
        """Is this node ready? Publish its state if that (or what it knows) changed."""
        if not self.started:
            return
        self.states[self.name] = self.own_state()
        missing = [n for n in self.run_nodes if n not in self.states]
        waiting = [f'the state of {n}' for n in missing]
        if not missing:
            pubs, subs = self._own_endpoints()
            waiting += self._unmatched(pubs, readers=True)
            waiting += self._unmatched(subs, readers=False)
        ready = not waiting
        self.ready = ready
        self.waiting_for = ', '.join(waiting[:4]) + (' ...' if len(waiting) > 4 else '')
        self._ready_with = self.instances() if ready else None
        state = self.own_state()
        self.states[self.name] = state
        if os.environ.get('TILTROV_HANDSHAKE_DEBUG') and (
                self._published is None or state.waiting_for != self._published.waiting_for):
            self.node.get_logger().info(f'handshake: {self.waiting_for or "ready"}')
        if state != self._published:
            self._published = state
            self._pub.publish(state.to_message(self.node.get_fully_qualified_name()))
        self._changed()

    def _unmatched(self, endpoints: Iterable[Any], *, readers: bool) -> list[str]:
        """What the node's ``endpoints`` (its writers if ``readers``: their readers are
        the peers) still wait for: a run node's peer endpoint not in the graph, or an
        endpoint in the graph not matched yet."""
        waiting: list[str] = []
        for endpoint in endpoints:
            topic = endpoint.topic_name
            infos, missing = unmatched(self.node, endpoint, publisher=readers)
            seen = {_gid(i) for i in infos}
            absent = sorted({n for n, s in self.states.items() if n != self.name
                             for t, gid in (s.subscribes if readers else s.publishes)
                             if t == topic and gid not in seen})
            waiting += [f'{n} on {topic}' for n in absent]
            if not absent and missing:
                waiting.append(f'{missing} match(es) on {topic}')
        return waiting

    def _changed(self) -> None:
        if self.run_ready():
            ready_with = self.instances()
            if ready_with != getattr(self, '_run_ready_with', None):
                self._run_ready_with = ready_with
                self.generation += 1
        if self.on_change is not None:
            self.on_change()

    def run_ready(self) -> bool:
        """Every run node is ready, with the latest instance of every run node."""
        if not self.active:
            return True
        if any(n not in self.states for n in self.run_nodes):
            return False
        instances = {n: self.states[n].instance for n in self.run_nodes}
        return all(self.states[n].ready and dict(self.states[n].peers) == instances
                   for n in self.run_nodes)

    def run_waiting_for(self) -> str:
        """What the run waits for, node by node ('' once it is ready)."""
        if self.run_ready():
            return ''
        parts = []
        instances = self.instances()
        for n in self.run_nodes:
            state = self.states.get(n)
            if state is None:
                parts.append(f'{n} (not started)')
            elif not state.ready:
                parts.append(f'{n} ({state.waiting_for})')
            elif dict(state.peers) != instances:
                parts.append(f'{n} (to see the latest instances)')
        return '; '.join(parts)

    def state_of(self, name: str) -> NodeState | None:
        return self.states.get(name)
