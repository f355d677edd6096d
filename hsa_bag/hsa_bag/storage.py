"""Writing rosbag2 bags (Jazzy layout, metadata version 9, MCAP storage) that split and survive a
killed writer.

Layout, as rosbag2 Jazzy writes it: one directory ``<name>/`` holding ``<name>_0.mcap``,
``<name>_1.mcap``, … and one ``metadata.yaml`` whose ``relative_file_paths`` and ``files`` list
them. Every file is written by a rosbags ``Writer`` (which owns a directory of its own): the writer
is opened in a staging directory ``<name>/<name>_<k>/``, its freshly created file is moved up to
``<name>/<name>_<k>.mcap`` while open, and the staging directory removed. The file's own metadata
(which rosbags also embeds in the MCAP) is merged into the bag's ``metadata.yaml``.

Crash safety: the pending MCAP chunk is closed and flushed to the operating system when it exceeds
``chunk_size`` bytes and on :meth:`SplitBagWriter.flush` (the recorder calls it periodically), and
``metadata.yaml`` is rewritten atomically whenever a split is closed. After a SIGKILL the closed
splits therefore form a complete, listed bag, and the open split holds every flushed chunk but no
summary or footer; :mod:`hsa_bag.recover` completes it. (Flushing hands the bytes to the kernel,
which survives a killed process; it does not fsync against power loss.)

Two McapWriter internals of rosbags 0.11.9 are used, in :class:`SplitFile` only: the pending
``chunk`` buffer with ``close_chunk()`` (rosbags itself closes chunks at 1 MiB only) and the file
object ``bio`` to flush; and its ``close(version, metadata)`` is wrapped to record ``ros_distro:
jazzy`` (rosbags writes its own name there) in the metadata embedded in the MCAP, as in
``metadata.yaml``.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rosbags.interfaces import Connection, Qos
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys.store import Typestore
from ruamel.yaml import YAML

VERSION = 9  # rosbag2 metadata version written by Jazzy
# the distribution whose bag layout and message definitions we write (rosbags writes "rosbags")
ROS_DISTRO = "jazzy"
METADATA = "metadata.yaml"
MAX_CHUNK_SIZE = 2**20  # rosbags closes chunks at 1 MiB by itself; smaller limits are ours
Info = dict[str, Any]  # the content of ``rosbag2_bagfile_information``


def _yaml() -> YAML:
    """A YAML dumper/loader formatted like the rosbags (and rosbag2) metadata files, without folded
    long lines."""
    yaml = YAML(typ="safe")
    yaml.default_flow_style = False
    yaml.width = 4096
    return yaml


def read_metadata(directory: Path) -> Info:
    """The ``rosbag2_bagfile_information`` mapping of a bag directory's metadata.yaml."""
    with open(directory / METADATA, encoding="utf8") as handle:
        return _yaml().load(handle)["rosbag2_bagfile_information"]


def write_metadata(directory: Path, info: Info) -> None:
    """Write metadata.yaml atomically (a reader never sees a half-written file)."""
    text = io.StringIO()
    _yaml().dump({"rosbag2_bagfile_information": info}, text)
    tmp = directory / f".{METADATA}.tmp"
    tmp.write_text(text.getvalue(), encoding="utf8")
    tmp.replace(directory / METADATA)


def merge_info(total: Info | None, part: Info) -> Info:
    """Bag information of ``total``'s files followed by the files of ``part`` (counts summed, span
    widened)."""
    if total is None:
        return part
    merged = dict(part)
    files = [*total["files"], *part["files"]]
    merged["relative_file_paths"] = [*total["relative_file_paths"], *part["relative_file_paths"]]
    merged["files"] = files
    merged["message_count"] = total["message_count"] + part["message_count"]
    with_messages = [f for f in files if f["message_count"]]
    if with_messages:
        start = min(f["starting_time"]["nanoseconds_since_epoch"] for f in with_messages)
        end = max(
            f["starting_time"]["nanoseconds_since_epoch"] + f["duration"]["nanoseconds"]
            for f in with_messages
        )
    else:
        start = end = part["starting_time"]["nanoseconds_since_epoch"]
    merged["starting_time"] = {"nanoseconds_since_epoch": start}
    merged["duration"] = {"nanoseconds": end - start}
    topics: dict[tuple[str, str], dict[str, Any]] = {}
    for entry in [*total["topics_with_message_count"], *part["topics_with_message_count"]]:
        meta = entry["topic_metadata"]
        key = (meta["name"], meta["type"])
        count = topics[key]["message_count"] if key in topics else 0
        topics[key] = {
            "topic_metadata": meta,
            "message_count": count + entry["message_count"],  # latest QoS wins
        }
    merged["topics_with_message_count"] = list(topics.values())
    return merged


@dataclass
class Topic:
    """A topic of a bag being written: name, type, the QoS profiles its publishers offered, messages
    written."""

    name: str
    msgtype: str
    qos: list[Qos]
    count: int = 0


class SplitFile:
    """One MCAP file ``<directory>/<stem>.mcap`` of a bag, written by a rosbags Writer, with
    explicit chunk flushes."""

    def __init__(
        self, directory: Path, stem: str, custom_data: dict[str, str] | None = None
    ) -> None:
        staging = directory / stem
        self.path = directory / f"{stem}.mcap"
        if self.path.exists():
            raise FileExistsError(f"{self.path} exists already, not overwriting")
        self._writer = Writer(staging, version=VERSION, storage_plugin=StoragePlugin.MCAP)
        for key, value in (custom_data or {}).items():
            self._writer.set_custom_data(key, value)
        self._writer.open()
        storage = self._writer.storage
        assert storage is not None
        storage.path.rename(self.path)  # the open file handle follows the rename
        storage.path = self.path
        staging.rmdir()
        # close() leaves this file's own metadata here
        self._writer.metapath = directory / f".{stem}.{METADATA}"
        self.first_timestamp: int | None = None  # of the first message written

    def set_custom_data(self, key: str, value: str) -> None:
        """Set a ``custom_data`` entry of this file's metadata (written at close)."""
        self._writer.set_custom_data(key, value)

    def add_connection(self, topic: Topic, typestore: Typestore) -> Connection:
        """Register a topic in this file (its schema from ``typestore``, its offered QoS in the
        channel metadata)."""
        return self._writer.add_connection(
            topic.name, topic.msgtype, typestore=typestore, offered_qos_profiles=topic.qos
        )

    def write(self, connection: Connection, timestamp: int, data: bytes | memoryview) -> None:
        """Append one serialized message with its timestamp [ns]."""
        self._writer.write(connection, timestamp, data)
        if self.first_timestamp is None:
            self.first_timestamp = timestamp

    @property
    def size(self) -> int:
        """Bytes written to the file so far plus the pending chunk."""
        storage = self._writer.storage
        assert storage is not None
        return storage.bio.tell() + storage.chunk.bio.tell()

    @property
    def pending(self) -> int:
        """Bytes in the pending (not yet written) chunk."""
        storage = self._writer.storage
        assert storage is not None
        return storage.chunk.bio.tell()

    def flush(self) -> None:
        """Close the pending chunk if it holds messages and hand the file's bytes to the operating
        system."""
        storage = self._writer.storage
        assert storage is not None
        if storage.chunk.msgs:
            storage.close_chunk()
        storage.bio.flush()

    def close(self) -> Info:
        """Write the summary and footer; return the file's bag information (relative to the bag
        directory)."""
        storage = self._writer.storage
        assert storage is not None
        close_storage = storage.close

        def close_as_jazzy(version: int, metadata: str) -> None:
            """Embed the file's metadata with our ``ros_distro`` instead of rosbags' own name."""
            info = _yaml().load(metadata)
            info["ros_distro"] = ROS_DISTRO
            text = io.StringIO()
            _yaml().dump(info, text)
            close_storage(version, text.getvalue().strip())

        storage.close = close_as_jazzy  # type: ignore[method-assign]
        self._writer.close()
        metapath = self._writer.metapath
        with open(metapath, encoding="utf8") as handle:
            info: Info = _yaml().load(handle)["rosbag2_bagfile_information"]
        metapath.unlink()
        info["ros_distro"] = ROS_DISTRO
        return info


class SplitBagWriter:
    """A rosbag2 MCAP bag directory written split by split; see the module docstring for layout and
    crash safety.

    A new split starts before a message that would make the current file larger than ``max_bytes``
    or that comes ``max_duration`` ns or more after the split's first message (0 disables either).
    Every split registers every topic known so far, as rosbag2 does, so each file is a
    self-contained MCAP.
    """

    def __init__(
        self,
        path: Path,
        typestore: Typestore,
        *,
        max_bytes: int = 0,
        max_duration: int = 0,
        chunk_size: int = 64 * 1024,
        custom_data: dict[str, str] | None = None,
    ) -> None:
        if not 0 < chunk_size <= MAX_CHUNK_SIZE:
            raise ValueError(f"chunk_size must be in (0, {MAX_CHUNK_SIZE}] bytes, got {chunk_size}")
        self.path = Path(path)
        self.typestore = typestore
        self.max_bytes = max_bytes
        self.max_duration = max_duration
        self.chunk_size = chunk_size
        self.custom_data = dict(custom_data or {})
        self.topics: list[Topic] = []
        self.info: Info | None = None  # closed splits
        self._file: SplitFile | None = None
        self._connections: list[Connection] = []  # of the open split, indexed like self.topics
        self._split_index = 0

    @property
    def files(self) -> list[Path]:
        """The files written so far (closed splits and the open one)."""
        closed = [self.path / p for p in self.info["relative_file_paths"]] if self.info else []
        return closed + ([self._file.path] if self._file else [])

    @property
    def message_count(self) -> int:
        """Messages written so far."""
        return sum(t.count for t in self.topics)

    def open(self) -> None:
        """Create the bag directory (refusing an existing path) and the first split."""
        self.path.mkdir(parents=True, exist_ok=False)
        self._open_split()

    def add_topic(self, name: str, msgtype: str, qos: Sequence[Qos]) -> int:
        """Register a topic (its type must be known to the typestore); return the handle for
        :meth:`write`."""
        topic = Topic(name, msgtype, list(qos))
        connection = self._open().add_connection(topic, self.typestore)
        self.topics.append(topic)
        self._connections.append(connection)
        return len(self.topics) - 1

    def set_custom_data(self, key: str, value: str) -> None:
        """Set a ``custom_data`` entry; the open split and every later one carry it, so the bag's
        metadata.yaml (the last split's) has the latest value."""
        self.custom_data[key] = value
        if self._file is not None:
            self._file.set_custom_data(key, value)

    def set_qos(self, handle: int, qos: Sequence[Qos]) -> None:
        """Replace the offered QoS profiles of a topic; they are stored from the next split on."""
        self.topics[handle].qos = list(qos)

    def write(self, handle: int, timestamp: int, data: bytes | memoryview) -> None:
        """Write one serialized message of topic ``handle`` with its timestamp [ns], splitting first
        if due."""
        current = self._open()
        if self._split_due(current, timestamp, len(data)):
            self._close_split()
            current = self._open_split()
        current.write(self._connections[handle], timestamp, data)
        self.topics[handle].count += 1
        if current.pending >= self.chunk_size:
            current.flush()

    def flush(self) -> None:
        """Make everything written so far survive a killed process (closes the pending chunk)."""
        if self._file is not None:
            self._file.flush()

    def close(self) -> None:
        """Close the open split and write the final metadata.yaml."""
        if self._file is not None:
            self._close_split()

    def _open(self) -> SplitFile:
        """The open split (raises if the bag was not opened or is closed)."""
        if self._file is None:
            raise RuntimeError(f"bag {self.path} is not open")
        return self._file

    def _split_due(self, current: SplitFile, timestamp: int, size: int) -> bool:
        """Whether a message of ``size`` bytes at ``timestamp`` belongs in a new split (never in an
        empty one).

        The size limit counts messages and chunk indexes; the summary and footer written at close
        come on top.
        """
        if current.first_timestamp is None:
            return False
        too_big = self.max_bytes > 0 and current.size + size > self.max_bytes
        too_long = (
            self.max_duration > 0 and timestamp - current.first_timestamp >= self.max_duration
        )
        return too_big or too_long

    def _open_split(self) -> SplitFile:
        """Start file ``<name>_<k>.mcap`` and register every known topic in it."""
        self._file = SplitFile(self.path, f"{self.path.name}_{self._split_index}", self.custom_data)
        self._split_index += 1
        self._connections = [self._file.add_connection(t, self.typestore) for t in self.topics]
        return self._file

    def _close_split(self) -> None:
        """Finish the open file and list it in metadata.yaml."""
        current = self._open()
        self._file = None
        self.info = merge_info(self.info, current.close())
        write_metadata(self.path, self.info)
