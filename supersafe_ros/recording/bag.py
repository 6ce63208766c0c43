"""A rosbag2 bag with MCAP storage, written by rosbags: (topic, type, CDR bytes, time) in.

rosbags' ``rosbag2.Writer`` (version 9, ``StoragePlugin.MCAP``, zstd-compressed chunks)
writes the folder ``ros2 bag play <bag>`` opens:

    <bag>/
      metadata.yaml            rosbag2_bagfile_information, version 9, storage_identifier mcap
      <bag name>.mcap          profile 'ros2'; schema per type: 'pkg/msg/Type', encoding
                               'ros2msg', data = the definition with its dependencies;
                               channel per topic: message encoding 'cdr', metadata
                               offered_qos_profiles (YAML); a 'rosbag2' metadata record
                               with serialized_metadata (the same YAML as metadata.yaml)

Message definitions and RIHS01 type hashes come from rosbags' Jazzy typestore
(``get_typestore(Stores.ROS2_JAZZY)``): a type it does not know, or a publisher whose type
hash differs from Jazzy's, raises ``DefinitionNotFound`` (its bytes could not be decoded
from the bag). Each message is written with one time, the receive time (rosbags writes it
as both MCAP log and publish time).

QoS profiles are plain dicts with rosbag2's keys (see ``qos_profile``). The writer is
thread-safe; ``close()`` finishes the MCAP summary and writes metadata.yaml. A bag that was
never closed (killed process) keeps every finished chunk (1 MB) but has no summary and no
metadata.yaml.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import functools
import threading
from pathlib import Path

STORAGE_ID = 'mcap'
METADATA_VERSION = 9
INFINITE_NS = 2**63 - 1     # RMW_DURATION_INFINITE, written as {sec: 9223372036, nsec: 854775807}


class DefinitionNotFound(LookupError):
    """A type the Jazzy typestore does not describe (or describes with another hash)."""


@functools.lru_cache(maxsize=None)
def typestore():
    """rosbags' typestore of ROS 2 Jazzy's message types (definitions and hashes)."""
    from rosbags.typesys import Stores, get_typestore
    return get_typestore(Stores.ROS2_JAZZY)


def duration_yaml(nanoseconds: int | None) -> dict:
    """rmw_time_t as rosbag2 writes it: {sec, nsec}; None or >= 2^63-1 ns is infinite."""
    if nanoseconds is None or nanoseconds >= INFINITE_NS:
        nanoseconds = INFINITE_NS
    sec, nsec = divmod(int(nanoseconds), 1_000_000_000)
    return {'sec': sec, 'nsec': nsec}


def qos_profile(history: str = 'keep_last', depth: int = 10, reliability: str = 'reliable',
                durability: str = 'volatile', deadline_ns: int = 0, lifespan_ns: int = 0,
                liveliness: str = 'automatic', lease_ns: int = 0,
                avoid_ros_namespace_conventions: bool = False) -> dict:
    """One offered QoS profile in rosbag2's version-9 YAML form (policy names as rmw spells
    them: keep_last|keep_all, reliable|best_effort, volatile|transient_local, automatic|
    manual_by_topic; 0 ns = unspecified)."""
    dur = lambda ns: {'sec': 0, 'nsec': 0} if not ns else duration_yaml(ns)  # noqa: E731
    return {'history': history, 'depth': int(depth), 'reliability': reliability,
            'durability': durability, 'deadline': dur(deadline_ns), 'lifespan': dur(lifespan_ns),
            'liveliness': liveliness, 'liveliness_lease_duration': dur(lease_ns),
            'avoid_ros_namespace_conventions': bool(avoid_ros_namespace_conventions)}


def rosbags_qos(profile: dict):
    """A ``qos_profile`` dict as rosbags' Qos (policy names -> its enums by name)."""
    from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness, QosReliability,
                                    QosTime)
    time = lambda d: QosTime(int(d['sec']), int(d['nsec']))  # noqa: E731
    return Qos(QosHistory[profile['history'].upper()], int(profile['depth']),
               QosReliability[profile['reliability'].upper()],
               QosDurability[profile['durability'].upper()], time(profile['deadline']),
               time(profile['lifespan']), QosLiveliness[profile['liveliness'].upper()],
               time(profile['liveliness_lease_duration']),
               bool(profile['avoid_ros_namespace_conventions']))


@dataclass
class _Topic:
    name: str
    type: str
    connection: object
    count: int = 0


@dataclass
class BagInfo:
    """What a closed bag holds (as metadata.yaml says)."""

    path: Path
    mcap_path: Path
    message_count: int
    topics: dict = field(default_factory=dict)   # topic -> message count


class BagWriter:
    """Writes one rosbag2 bag folder with one MCAP file (rosbags' writer)."""

    def __init__(self, path: str | Path):
        from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
        self.path = Path(path)
        if self.path.exists():
            if not self.path.is_dir() or any(self.path.iterdir()):
                raise FileExistsError(f'{self.path} exists and is not an empty folder: '
                                      'a bag is never overwritten')
            self.path.rmdir()       # rosbags creates the folder itself
        self._writer = Writer(self.path, version=METADATA_VERSION, storage_plugin=StoragePlugin.MCAP)
        # zstd chunks (compression inside the storage: metadata.yaml says no file compression)
        self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        self._writer.open()
        self.mcap_path = self.path / f'{self.path.name}.mcap'
        self._lock = threading.Lock()
        self.topics: dict[str, _Topic] = {}
        self.message_count = 0
        self.closed = False

    def add_topic(self, topic: str, type_name: str, offered_qos: list[dict] | None = None,
                  type_hash: str | None = None) -> None:
        """Register a topic (once; a second call for the same topic is ignored).

        ``type_name`` is 'pkg/msg/Type'; ``type_hash`` (the publisher's RIHS01, if known) must
        be Jazzy's. Raises DefinitionNotFound otherwise."""
        store = typestore()
        if type_name not in store.fielddefs:
            raise DefinitionNotFound(f'{type_name} is not a ROS 2 Jazzy type rosbags knows')
        jazzy_hash = store.hash_rihs01(type_name)
        if type_hash and type_hash != jazzy_hash:
            raise DefinitionNotFound(f'{type_name}: the publisher\'s type hash {type_hash} is not '
                                     f'Jazzy\'s {jazzy_hash}')
        with self._lock:
            if self.closed or topic in self.topics:
                return
            connection = self._writer.add_connection(
                topic, type_name, typestore=store,
                offered_qos_profiles=[rosbags_qos(q) for q in offered_qos or []])
            self.topics[topic] = _Topic(topic, type_name, connection)

    def write(self, topic: str, data: bytes, log_time_ns: int) -> bool:
        """Append one serialized (CDR) message of a registered topic; False once closed."""
        with self._lock:
            if self.closed:
                return False
            t = self.topics[topic]
            self._writer.write(t.connection, int(log_time_ns), data)
            t.count += 1
            self.message_count += 1
            return True

    def close(self) -> BagInfo:
        """Finish the MCAP file and write metadata.yaml (idempotent)."""
        with self._lock:
            if not self.closed:
                self.closed = True
                self._writer.close()
            return BagInfo(self.path, self.mcap_path, self.message_count,
                           {t.name: t.count for t in self.topics.values()})

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
