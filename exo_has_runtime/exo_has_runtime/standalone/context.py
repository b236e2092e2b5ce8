"""The process-wide context of the standalone backend: one Cyclone DDS participant, as rmw.

The participant is created with the first node, as rmw_cyclonedds_cpp creates it, on the domain
``ROS_DOMAIN_ID`` (default 0), with USER_DATA ``enclave=<enclave>;``. Without CYCLONEDDS_URI the
domain gets a loopback-only configuration: rmw_cyclonedds_cpp's ROS_AUTOMATIC_DISCOVERY_RANGE=
LOCALHOST settings (no multicast, unicast discovery to localhost, up to 33 participants) plus the
loopback interface, so processes on one machine find each other and nothing leaves it.

The context also publishes ``ros_discovery_info`` (rmw_dds_common/msg/ParticipantEntitiesInfo),
through which ``ros2 node list`` on a ROS 2 machine lists standalone nodes, and keeps a view of
the DDS graph (who publishes and subscribes what) from the DDS built-in topics.
"""

from __future__ import annotations

import os
import signal
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from types import FrameType
from typing import Any

from cyclonedds.builtin import (
    BuiltinDataReader,
    BuiltinTopicDcpsPublication,
    BuiltinTopicDcpsSubscription,
)
from cyclonedds.core import GuardCondition, InstanceState, ReadCondition, SampleState, ViewState
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy, Qos
from cyclonedds.topic import Topic

from exo_has_runtime.arguments import RosArguments, parse_ros_args
from exo_has_runtime.dds_config import LOOPBACK_CONFIG
from exo_has_runtime.errors import BackendError, TopicTypeMismatchError
from exo_has_runtime.standalone.logging import get_logger, set_default_levels
from exo_has_runtime.standalone.messages import MessageRegistry, default_registry

DISCOVERY_TOPIC = 'ros_discovery_info'
DISCOVERY_TYPE = 'rmw_dds_common/msg/ParticipantEntitiesInfo'
_ANY_STATE = SampleState.Any | ViewState.Any | InstanceState.Any


def domain_id_from_environment() -> int:
    """Return ROS_DOMAIN_ID (0 when unset or empty).

    Raises
    ------
    BackendError
        If it is not a whole number from 0 to 232 (the range ROS 2 documents for UDP ports).

    """
    text = os.environ.get('ROS_DOMAIN_ID', '').strip()
    if not text:
        return 0
    if not text.isdigit() or int(text) > 232:
        msg = f'ROS_DOMAIN_ID={text!r}: expected a whole number from 0 to 232'
        raise BackendError(msg)
    return int(text)


def delete_entity(entity: Any) -> None:
    """Delete a DDS entity now, so that peers see it leave at once.

    The Python binding deletes entities when they are garbage collected; its ``__del__`` is
    idempotent, so calling it early is safe.
    """
    entity.__del__()


def gid_of(entity: Any) -> bytes:
    """Return the 16-byte ROS gid of a DDS entity: its GUID, prefix then entity id."""
    return bytes(entity.get_guid().bytes)


@dataclass
class GraphEndpoint:
    """A reader or writer seen through DDS discovery."""

    topic_name: str
    type_name: str
    participant: bytes
    is_writer: bool
    #: The endpoint's DDS QoS (cyclonedds.qos.Qos), None when discovery did not carry it.
    qos: Any = None
    #: The endpoint's GUID, which is its ROS gid.
    key: bytes = b''


@dataclass
class _NodeEntry:
    name: str
    namespace: str
    readers: list[bytes]
    writers: list[bytes]


class Context:
    """Initialisation state, participant and graph of one process, as ``rclpy.context.Context``."""

    def __init__(self) -> None:
        self._lock = threading.RLock()
        self._ok = False
        self._external_shutdown = False
        self.arguments = RosArguments()
        self._participant: DomainParticipant | None = None
        self._guard: GuardCondition | None = None
        self._discovery_writer: DataWriter[Any] | None = None
        self._topics: dict[str, tuple[str, Topic[Any]]] = {}
        self._nodes: dict[int, _NodeEntry] = {}
        self._graph: dict[bytes, GraphEndpoint] = {}
        self._graph_readers: list[BuiltinDataReader] = []
        self._graph_conditions: list[ReadCondition] = []
        self._mismatch_warned: set[tuple[str, str]] = set()
        self._previous_sigterm: Any = None
        self.registry: MessageRegistry | None = None

    def init(self, args: Sequence[str] | None = None) -> None:
        """Parse the ROS arguments and make the context usable.

        Raises
        ------
        RuntimeError
            If the context is initialised already.
        CommandLineError
            If the ROS arguments are malformed.

        """
        with self._lock:
            if self._ok:
                raise RuntimeError('Context.init() must only be called once')
            self._external_shutdown = False
            import sys
            self.arguments = parse_ros_args(list(sys.argv if args is None else args))
            set_default_levels(self.arguments.log_levels)
            self.registry = default_registry()
            self._ok = True
            self._external_shutdown = False
            if threading.current_thread() is threading.main_thread():
                self._previous_sigterm = signal.signal(signal.SIGTERM, self._on_sigterm)

    def _on_sigterm(self, signum: int, frame: FrameType | None) -> None:
        # Runs between two bytecodes of the main thread, possibly inside shutdown() or
        # participant creation: only request, and wake the executor, which shuts down.
        self._external_shutdown = True
        guard = self._guard
        if guard is not None:
            guard.set(True)

    def ok(self) -> bool:
        """Whether the context is initialised and neither shut down nor asked to by SIGTERM."""
        return self._ok and not self._external_shutdown

    @property
    def shut_down_externally(self) -> bool:
        """Whether a SIGTERM asked the context to shut down."""
        return self._external_shutdown

    def shutdown(self) -> None:
        """Shut the context down: wake every waiting executor and leave the DDS domain.

        Raises
        ------
        RuntimeError
            If the context is not initialised.

        """
        with self._lock:
            if not self._ok:
                raise RuntimeError('Context must be initialized before it can be shutdown')
            self._ok = False
            self._nodes.clear()
            if self._guard is not None:
                self._guard.set(True)
            if self._participant is not None:
                # Leave the domain at once: peers see the endpoints go, and the participant
                # index (at most 33 per machine with the loopback configuration) is freed.
                delete_entity(self._participant)
                self._participant = None
                self._guard = None
                self._discovery_writer = None
                self._topics.clear()
                self._graph.clear()
                self._graph_readers.clear()
                self._graph_conditions.clear()
            if self._previous_sigterm is not None \
                    and threading.current_thread() is threading.main_thread():
                signal.signal(signal.SIGTERM, self._previous_sigterm)
                self._previous_sigterm = None

    def try_shutdown(self) -> None:
        """Shut down if not shut down already."""
        with self._lock:
            if self._ok:
                self.shutdown()

    @property
    def guard_condition(self) -> GuardCondition:
        """Condition triggered on shutdown, which executors wait on."""
        self.participant  # noqa: B018  (creates the guard condition with the participant)
        assert self._guard is not None
        return self._guard

    @property
    def participant(self) -> DomainParticipant:
        """The DDS participant, created on first use."""
        with self._lock:
            if self._participant is None:
                self._participant = self._create_participant()
            return self._participant

    def _create_participant(self) -> DomainParticipant:
        if not self._ok:
            raise RuntimeError('the context is not initialised: call init() first')
        os.environ.setdefault('CYCLONEDDS_URI', LOOPBACK_CONFIG)
        user_data = f'enclave={self.arguments.enclave};'.encode()
        participant = DomainParticipant(domain_id_from_environment(),
                                        qos=Qos(Policy.Userdata(user_data)))
        self._guard = GuardCondition(participant)
        registry = self.message_registry
        discovery_type = registry.get_message(DISCOVERY_TYPE)
        topic = Topic(participant, DISCOVERY_TOPIC, discovery_type)
        self._topics[DISCOVERY_TOPIC] = (DISCOVERY_TYPE, topic)
        type_hash = registry.type_hash(DISCOVERY_TYPE)
        self._discovery_writer = DataWriter(participant, topic, qos=Qos(
            Policy.Userdata(f'typehash={type_hash};'.encode()),
            Policy.WriterDataLifecycle(autodispose=False),
            Policy.History.KeepLast(1),
            Policy.Reliability.Reliable(max_blocking_time=0x7FFFFFFFFFFFFFFF),
            Policy.Durability.TransientLocal,
            Policy.DurabilityService(cleanup_delay=0, history=Policy.History.KeepLast(1),
                                     max_samples=-1, max_instances=-1,
                                     max_samples_per_instance=-1),
            Policy.DataRepresentation(use_cdrv0_representation=True)))
        for builtin in (BuiltinTopicDcpsPublication, BuiltinTopicDcpsSubscription):
            reader = BuiltinDataReader(participant, builtin)
            self._graph_readers.append(reader)
            self._graph_conditions.append(ReadCondition(reader, _ANY_STATE))
        return participant

    @property
    def message_registry(self) -> MessageRegistry:
        """The message registry of this context."""
        if self.registry is None:
            self.registry = default_registry()
        return self.registry

    @property
    def graph_conditions(self) -> list[ReadCondition]:
        """Conditions triggered by discovery data, which executors wait on."""
        self.participant  # noqa: B018
        return self._graph_conditions

    def topic(self, dds_name: str, type_name: str, message_class: type[Any]) -> Topic[Any]:
        """Return the DDS topic of this name, creating it for the given type.

        Raises
        ------
        TopicTypeMismatchError
            If this process already uses the topic with another type.

        """
        with self._lock:
            known = self._topics.get(dds_name)
            if known is not None:
                if known[0] != type_name:
                    msg = (
                        f'topic {dds_name!r} is already used in this process with type '
                        f'{known[0]}; it cannot also carry {type_name}'
                    )
                    raise TopicTypeMismatchError(msg)
                return known[1]
            topic = Topic(self.participant, dds_name, message_class)
            self._topics[dds_name] = (type_name, topic)
            return topic

    def add_node(self, key: int, name: str, namespace: str) -> None:
        """Register a node for ros_discovery_info."""
        with self._lock:
            self._nodes[key] = _NodeEntry(name, namespace, [], [])
            self.publish_discovery_info()

    def remove_node(self, key: int) -> None:
        """Unregister a node."""
        with self._lock:
            self._nodes.pop(key, None)
            if self._ok:
                self.publish_discovery_info()

    def add_endpoint(self, key: int, gid: bytes, is_writer: bool) -> None:
        """Register a node's reader or writer gid."""
        with self._lock:
            entry = self._nodes[key]
            (entry.writers if is_writer else entry.readers).append(gid)
            self.publish_discovery_info()

    def remove_endpoint(self, key: int, gid: bytes) -> None:
        """Unregister a node's reader or writer gid."""
        with self._lock:
            entry = self._nodes.get(key)
            if entry is None:
                return
            for gids in (entry.readers, entry.writers):
                if gid in gids:
                    gids.remove(gid)
            if self._ok:
                self.publish_discovery_info()

    def publish_discovery_info(self) -> None:
        """Publish the participant's node list on ros_discovery_info."""
        registry = self.message_registry
        gid_class = registry.get_message('rmw_dds_common/msg/Gid')
        node_class = registry.get_message('rmw_dds_common/msg/NodeEntitiesInfo')
        info_class = registry.get_message(DISCOVERY_TYPE)
        participant = self.participant
        info = info_class(gid=gid_class(data=list(gid_of(participant))))
        for entry in self._nodes.values():
            info.node_entities_info_seq.append(node_class(
                node_namespace=entry.namespace, node_name=entry.name,
                reader_gid_seq=[gid_class(data=list(g)) for g in entry.readers],
                writer_gid_seq=[gid_class(data=list(g)) for g in entry.writers]))
        assert self._discovery_writer is not None
        self._discovery_writer.write(info)

    def refresh_graph(self) -> None:
        """Take new discovery data and warn of topics used with conflicting types."""
        with self._lock:
            self.participant  # noqa: B018
            for reader in self._graph_readers:
                for sample in _take_holding_sigint(reader):
                    key = bytes(sample.key.bytes)
                    if sample.sample_info.instance_state != InstanceState.Alive:
                        self._graph.pop(key, None)
                        continue
                    self._graph[key] = GraphEndpoint(
                        sample.topic_name, sample.type_name,
                        bytes(sample.participant_key.bytes),
                        reader.topic is BuiltinTopicDcpsPublication, sample.qos, key)
            self._warn_type_mismatches()

    def _warn_type_mismatches(self) -> None:
        own = gid_of(self.participant)
        for endpoint in self._graph.values():
            if endpoint.participant == own:
                continue
            local = self._topics.get(endpoint.topic_name)
            if local is None or local[1].get_type_name() == endpoint.type_name:
                continue
            warned = (endpoint.topic_name, endpoint.type_name)
            if warned in self._mismatch_warned:
                continue
            self._mismatch_warned.add(warned)
            role = 'publisher' if endpoint.is_writer else 'subscriber'
            get_logger('exo_has_runtime').warning(
                f'topic {endpoint.topic_name!r}: a {role} in another process uses type '
                f'{endpoint.type_name}, this process uses {local[1].get_type_name()}; they '
                'will not communicate')

    def endpoints(self, dds_topic_name: str | None = None) -> list[GraphEndpoint]:
        """Return the readers and writers the graph knows, optionally of one DDS topic."""
        self.refresh_graph()
        return [e for e in self._graph.values()
                if dds_topic_name is None or e.topic_name == dds_topic_name]


_default_context = Context()


def get_default_context() -> Context:
    """Return the process-wide context."""
    return _default_context


def _take_holding_sigint(reader: Any) -> list[Any]:
    """Take up to 256 discovery samples, with a SIGINT held until the take is over.

    The DDS binding builds each builtin sample in a Python callback from C: a KeyboardInterrupt
    raised there comes out as a bare ``Exception`` ("Callfunc endpoint constructor errored")
    and the node would end with a traceback instead of stopping cleanly. Outside the main
    thread (where Python runs no signal handler) the take is left as it is.
    """
    if threading.current_thread() is not threading.main_thread():
        return list(reader.take(N=256))
    caught: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: caught.append(signum))
    try:
        return list(reader.take(N=256))
    finally:
        signal.signal(signal.SIGINT, previous)
        if caught:
            if callable(previous):
                previous(caught[0], None)
            elif previous == signal.SIG_DFL:
                raise KeyboardInterrupt
