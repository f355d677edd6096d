"""Reading bags for replay and analysis: validated opening, topics with their QoS, messages in
timestamp order.

A bag is a rosbag2 directory (metadata.yaml + MCAP files) or a single ``.mcap`` file. rosbags'
directory reader yields the files of a split bag one after the other, and nothing forces another
tool to keep its files in time order (ecosystem.md §2 item 10), so :meth:`Bag.messages` merges the
files' streams by timestamp; within one file rosbags' MCAP reader already merges the chunks in
timestamp order. Messages are decoded with the definitions stored in the bag itself, so no ROS
installation is needed. Every failure raises :class:`BagError` naming the file, topic or type at
fault; a single message that does not decode with its topic's definition (malformed CDR, as a
recorder that stores raw bytes may have kept) is not a failure of the bag: :meth:`Bag.decoded` skips
it and counts it in :attr:`Bag.skipped`.
"""

from __future__ import annotations

import heapq
from collections.abc import Collection, Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from types import TracebackType
from typing import Any

from rosbags.interfaces import Connection, ConnectionExtRosbag2, MessageDefinitionFormat, Qos
from rosbags.rosbag2 import Reader, ReaderError
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, TypesysError, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore
from ruamel.yaml import YAMLError

from hsa_bag.storage import METADATA, read_metadata


class BagError(Exception):
    """A bag cannot be used as asked; the message names the file, topic or type at fault."""


@dataclass(frozen=True)
class TopicInfo:
    """One topic of a bag: type, message definition, the QoS profiles its publishers offered,
    message count."""

    name: str
    msgtype: str
    msgdef: str
    msgdef_format: MessageDefinitionFormat
    qos: tuple[Qos, ...]
    count: int


def _recover_hint(bag: Path) -> str:
    """Advice for a bag whose recorder may have been killed."""
    return f"; if its recorder was killed, `bag_recover {bag}` completes it"


def _open_file(path: Path, bag: Path) -> Reader:
    """Open one MCAP file of ``bag``, naming the file in any error."""
    if not path.is_file():
        raise BagError(f"{bag}: file {path.name} listed in {METADATA} is missing")
    reader = Reader(path)
    try:
        reader.open()
    except ReaderError as exc:
        raise BagError(f"{path}: not a complete MCAP file ({exc}){_recover_hint(bag)}") from exc
    return reader


class Bag:
    """Read access to a bag (use as a context manager, or call :meth:`close`)."""

    def __init__(self, path: Path | str) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise BagError(f"{self.path}: no such bag (a rosbag2 directory or an .mcap file)")
        if self.path.is_dir():
            if not (self.path / METADATA).is_file():
                found = sorted(p.name for p in self.path.glob("*.mcap"))
                extra = f" (it holds {', '.join(found)}){_recover_hint(self.path)}" if found else ""
                raise BagError(f"{self.path}: {METADATA} is missing, not a rosbag2 bag{extra}")
            try:
                relative = read_metadata(self.path)["relative_file_paths"]
            except (OSError, YAMLError, KeyError, TypeError) as exc:
                raise BagError(
                    f"{self.path / METADATA}: unreadable bag metadata ({exc!r})"
                ) from exc
            self.files = [self.path / name for name in relative]
        elif self.path.suffix == ".mcap":
            self.files = [self.path]
        else:
            raise BagError(
                f"{self.path}: not a bag (expected a rosbag2 directory or an .mcap file)"
            )
        self._readers: list[Reader] = []
        self.skipped: dict[str, int] = {}  # topic -> messages :meth:`decoded` could not decode
        try:
            for file in self.files:
                self._readers.append(_open_file(file, self.path))
            if self.path.is_dir():
                self._validate_metadata()
            self.topics = self._read_topics()
        except BaseException:
            self.close()
            raise
        self.message_count = sum(r.message_count for r in self._readers)
        with_messages = [r for r in self._readers if r.message_count]
        self.start = min((r.start_time for r in with_messages), default=0)  # ns, first message
        self.end = max((r.end_time - 1 for r in with_messages), default=0)  # ns, last message

    def _validate_metadata(self) -> None:
        """Let rosbags check metadata.yaml as a whole (version, storage, topics)."""
        try:
            with Reader(self.path):
                pass
        except (ReaderError, KeyError, TypeError) as exc:
            raise BagError(f"{self.path / METADATA}: invalid bag metadata ({exc!r})") from exc

    def _read_topics(self) -> dict[str, TopicInfo]:
        """Topics of all files: definition from the first file that has the topic, QoS from the
        last, counts summed."""
        topics: dict[str, TopicInfo] = {}
        for reader in self._readers:
            for conn in reader.connections:
                qos = (
                    tuple(conn.ext.offered_qos_profiles)
                    if isinstance(conn.ext, ConnectionExtRosbag2)
                    else ()
                )
                known = topics.get(conn.topic)
                if known is None:
                    topics[conn.topic] = TopicInfo(
                        conn.topic,
                        conn.msgtype,
                        conn.msgdef.data,
                        conn.msgdef.format,
                        qos,
                        conn.msgcount,
                    )
                elif known.msgtype != conn.msgtype:
                    raise BagError(
                        f"{self.path}: topic {conn.topic} has two types, {known.msgtype} and "
                        f"{conn.msgtype}"
                    )
                else:
                    topics[conn.topic] = replace(
                        known, qos=qos or known.qos, count=known.count + conn.msgcount
                    )
        return topics

    def topic(self, name: str) -> TopicInfo:
        """The topic ``name``; BagError listing the bag's topics if it is absent."""
        if name not in self.topics:
            raise BagError(
                f"{self.path}: topic {name} is not in the bag (topics: "
                f"{', '.join(sorted(self.topics))})"
            )
        return self.topics[name]

    def messages(
        self, topics: Collection[str] | None = None, start: int | None = None
    ) -> Iterator[tuple[str, int, bytes]]:
        """(topic, timestamp [ns], serialized message) of the selected topics, in timestamp order
        across files."""
        wanted = set(self.topics if topics is None else topics)
        streams = []
        for reader in self._readers:
            conns: list[Connection] = [c for c in reader.connections if c.topic in wanted]
            if conns:
                streams.append(
                    (conn.topic, t, data) for conn, t, data in reader.messages(conns, start=start)
                )
        return heapq.merge(*streams, key=lambda item: item[1])

    def decoded(self, name: str) -> Iterator[tuple[int, Any]]:
        """(timestamp [ns], decoded message) of topic ``name`` in timestamp order; a message that
        does not decode is skipped and counted in ``skipped[name]``."""
        store = self.typestore(name)
        msgtype = self.topic(name).msgtype
        for _, timestamp, raw in self.messages([name]):
            try:
                msg = store.deserialize_cdr(raw, msgtype)
            except SerdeError:
                self.skipped[name] = self.skipped.get(name, 0) + 1
                continue
            yield timestamp, msg

    def typestore(self, name: str) -> Typestore:
        """A typestore that decodes topic ``name``: the definition stored in the bag, else the Jazzy
        one."""
        info = self.topic(name)
        where = f"{self.path}: type {info.msgtype} of topic {name} cannot be decoded"
        if info.msgdef_format == MessageDefinitionFormat.NONE:
            store = get_typestore(Stores.ROS2_JAZZY)
            if info.msgtype not in store.fielddefs:
                raise BagError(
                    f"{where}: the bag holds no definition and it is not a standard Jazzy type"
                )
            return store
        if info.msgdef_format != MessageDefinitionFormat.MSG:
            raise BagError(f"{where}: {info.msgdef_format.name} definitions are not supported")
        store = get_typestore(Stores.EMPTY)
        try:
            store.register(get_types_from_msg(info.msgdef, info.msgtype))
            # every nested type must resolve now, not at the first message
            store.get_msgdef(info.msgtype)
        except KeyError as exc:
            raise BagError(
                f"{where}: the bag's definition lacks the nested type {exc.args[0]}"
            ) from exc
        except TypesysError as exc:
            raise BagError(f"{where}: the bag's definition is invalid ({exc})") from exc
        return store

    def close(self) -> None:
        """Close every file."""
        for reader in self._readers:
            reader.close()
        self._readers = []

    def __enter__(self) -> Bag:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def stamp_ns(stamp: object) -> int:
    """A decoded builtin_interfaces/Time → integer nanoseconds (a float of epoch seconds resolves
    only ~0.2 µs).

    The ROS-free twin of ``hsa_common.convert.stamp_ns``: offline tools decode bags without
    importing ROS messages.
    """
    return stamp.sec * 1_000_000_000 + stamp.nanosec  # type: ignore[attr-defined]
