"""A rosbag2-layout MCAP bag writer that needs no ROS: (topic, type, CDR bytes, time) in.

Layout and fields follow rosbag2's MCAP storage plugin as of Jazzy
(rosbag2_storage_mcap/src/mcap_storage.cpp, rosbag2_storage/yaml.hpp and qos.cpp):

    <bag>/                     the folder ``ros2 bag play <bag>`` opens
      metadata.yaml            rosbag2_bagfile_information, version 9, storage_identifier mcap
      <bag name>_0.mcap        profile 'ros2'; schema per type: name 'pkg/msg/Type',
                               encoding 'ros2msg', data = full .msg text with dependencies;
                               channel per topic: message encoding 'cdr', metadata
                               offered_qos_profiles (YAML) and topic_type_hash (RIHS01_...);
                               message log_time = receive time, publish_time = source time;
                               a 'rosbag2' metadata record with serialized_metadata (the
                               same YAML as metadata.yaml) and ROS_DISTRO

``ros2 bag play <bag>/<bag name>_0.mcap`` also works (Jazzy reads the metadata from
the file itself), and Foxglove opens the .mcap directly.

QoS profiles are plain dicts with rosbag2's keys (see ``qos_profile``).
The writer is thread-safe; ``close()`` finishes the MCAP summary and writes
metadata.yaml. A bag that was never closed (killed process) keeps every finished
chunk; ``mcap recover`` rebuilds its summary.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import threading
from pathlib import Path

import yaml

from . import msgdefs

STORAGE_ID = 'mcap'
PROFILE = 'ros2'
MESSAGE_ENCODING = 'cdr'
METADATA_VERSION = 9
ROS_DISTRO = 'jazzy'
LIBRARY = 'supersafe_ros recording (python mcap)'
INFINITE_DURATION = {'sec': 9223372036, 'nsec': 854775807}   # RMW_DURATION_INFINITE
UNSPECIFIED_DURATION = {'sec': 0, 'nsec': 0}


def duration_yaml(nanoseconds: int | None) -> dict:
    """rmw_time_t as rosbag2 writes it: {sec, nsec}; None or >= 2^63-1 ns is infinite."""
    if nanoseconds is None or nanoseconds >= 2**63 - 1:
        return dict(INFINITE_DURATION)
    sec, nsec = divmod(int(nanoseconds), 1_000_000_000)
    return {'sec': sec, 'nsec': nsec}


def qos_profile(history: str = 'keep_last', depth: int = 10, reliability: str = 'reliable',
                durability: str = 'volatile', deadline_ns: int = 0, lifespan_ns: int = 0,
                liveliness: str = 'automatic', lease_ns: int = 0,
                avoid_ros_namespace_conventions: bool = False) -> dict:
    """One offered QoS profile in rosbag2's version-9 YAML form (policy names as rmw spells
    them: keep_last|keep_all, reliable|best_effort, volatile|transient_local, automatic|
    manual_by_topic; 0 ns = unspecified)."""
    dur = lambda ns: UNSPECIFIED_DURATION if not ns else duration_yaml(ns)  # noqa: E731
    return {'history': history, 'depth': int(depth), 'reliability': reliability,
            'durability': durability, 'deadline': dur(deadline_ns), 'lifespan': dur(lifespan_ns),
            'liveliness': liveliness, 'liveliness_lease_duration': dur(lease_ns),
            'avoid_ros_namespace_conventions': bool(avoid_ros_namespace_conventions)}


def qos_yaml(profiles: list[dict]) -> str:
    return yaml.safe_dump(list(profiles), default_flow_style=False, sort_keys=False)


@dataclass
class _Topic:
    name: str
    type: str
    channel_id: int
    qos: list
    type_hash: str
    count: int = 0


@dataclass
class BagInfo:
    """What a closed bag holds (as metadata.yaml says)."""

    path: Path
    mcap_path: Path
    message_count: int
    topics: dict = field(default_factory=dict)   # topic -> message count


class BagWriter:
    """Writes one rosbag2 bag folder with one MCAP file."""

    def __init__(self, path: str | Path, chunk_size: int = 1024 * 1024):
        from mcap.writer import CompressionType, Writer
        self.path = Path(path)
        if self.path.exists() and (not self.path.is_dir() or any(self.path.iterdir())):
            raise FileExistsError(f'{self.path} exists and is not an empty folder: '
                                  'a bag is never overwritten')
        self.path.mkdir(parents=True, exist_ok=True)
        self.file_name = f'{self.path.name}_0.mcap'
        self.mcap_path = self.path / self.file_name
        self._stream = open(self.mcap_path, 'wb')
        # zstd chunks: what rosbag2's zstd presets write; every MCAP reader decodes them
        self._writer = Writer(self._stream, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        self._writer.start(profile=PROFILE, library=LIBRARY)
        self._lock = threading.Lock()
        self._schemas: dict[str, int] = {}
        self.topics: dict[str, _Topic] = {}
        self.first_ns = None
        self.last_ns = None
        self.message_count = 0
        self.closed = False

    def add_topic(self, topic: str, type_name: str, offered_qos: list[dict] | None = None,
                  type_hash: str | None = None) -> None:
        """Register a topic (once; a second call for the same topic is ignored).

        ``type_name`` is 'pkg/msg/Type'. Raises msgdefs.DefinitionNotFound if the type's
        .msg is not installed (its messages could not be decoded from the bag)."""
        with self._lock:
            if self.closed or topic in self.topics:
                return
            schema_id = self._schemas.get(type_name)
            if schema_id is None:
                schema_id = self._writer.register_schema(
                    type_name, msgdefs.SCHEMA_ENCODING, msgdefs.full_text(type_name).encode())
                self._schemas[type_name] = schema_id
            qos = list(offered_qos or [])
            type_hash = msgdefs.type_hash(type_name) if type_hash is None else type_hash
            channel_id = self._writer.register_channel(
                topic, MESSAGE_ENCODING, schema_id,
                {'offered_qos_profiles': qos_yaml(qos), 'topic_type_hash': type_hash})
            self.topics[topic] = _Topic(topic, type_name, channel_id, qos, type_hash)

    def write(self, topic: str, data: bytes, log_time_ns: int, publish_time_ns: int | None = None) -> bool:
        """Append one serialized (CDR) message of a registered topic; False once closed."""
        with self._lock:
            if self.closed:
                return False
            t = self.topics[topic]
            self._writer.add_message(t.channel_id, log_time=int(log_time_ns), data=bytes(data),
                                     publish_time=int(log_time_ns if publish_time_ns is None
                                                      else publish_time_ns),
                                     sequence=t.count)
            t.count += 1
            self.message_count += 1
            self.first_ns = log_time_ns if self.first_ns is None else min(self.first_ns, log_time_ns)
            self.last_ns = log_time_ns if self.last_ns is None else max(self.last_ns, log_time_ns)
            return True

    def metadata(self) -> dict:
        """rosbag2_bagfile_information (version 9) of what was written so far."""
        start = self.first_ns or 0
        duration = (self.last_ns - self.first_ns) if self.first_ns is not None else 0
        topics = [{'topic_metadata': {'name': t.name, 'type': t.type,
                                      'serialization_format': MESSAGE_ENCODING,
                                      'offered_qos_profiles': t.qos,
                                      'type_description_hash': t.type_hash},
                   'message_count': t.count} for t in self.topics.values()]
        return {'rosbag2_bagfile_information': {
            'version': METADATA_VERSION,
            'storage_identifier': STORAGE_ID,
            'duration': {'nanoseconds': int(duration)},
            'starting_time': {'nanoseconds_since_epoch': int(start)},
            'message_count': self.message_count,
            'topics_with_message_count': topics,
            'compression_format': '',
            'compression_mode': '',
            'relative_file_paths': [self.file_name],
            'files': [{'path': self.file_name,
                       'starting_time': {'nanoseconds_since_epoch': int(start)},
                       'duration': {'nanoseconds': int(duration)},
                       'message_count': self.message_count}],
            'custom_data': {},
            'ros_distro': ROS_DISTRO,
        }}

    def close(self) -> BagInfo:
        """Finish the MCAP file and write metadata.yaml (idempotent)."""
        with self._lock:
            if not self.closed:
                self.closed = True
                meta = self.metadata()
                # the plugin reads its metadata (and the QoS format version) from this record:
                # the BagMetadata itself, without metadata.yaml's top-level key
                inner = yaml.safe_dump(meta['rosbag2_bagfile_information'], default_flow_style=False,
                                       sort_keys=False)
                self._writer.add_metadata('rosbag2', {'serialized_metadata': inner,
                                                      'ROS_DISTRO': ROS_DISTRO})
                self._writer.finish()
                self._stream.close()
                (self.path / 'metadata.yaml').write_text(
                    yaml.safe_dump(meta, default_flow_style=False, sort_keys=False))
            return BagInfo(self.path, self.mcap_path, self.message_count,
                           {t.name: t.count for t in self.topics.values()})

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
