"""Completing a bag whose recorder was killed, so that every flushed chunk of its unfinished split
can be read.

After a SIGKILL a bag directory written by :class:`hsa_bag.storage.SplitBagWriter` holds the closed
splits, listed in metadata.yaml, and one unfinished split: an MCAP file that ends after its last
flushed chunk, without summary and footer, which indexed readers (rosbags, ``ros2 bag``) refuse.
:func:`recover_bag` reads every unlisted ``.mcap`` file record by record with the ``mcap`` package's
stream reader up to the first incomplete record, writes the messages into a complete file of the
same name (the original stays as ``<file>.truncated`` until the new file is closed) and lists it in
metadata.yaml. Listed files are left alone.

Command line: ``bag_recover BAG [BAG ...]``; exit code 2 if a path is not a bag directory.
"""

from __future__ import annotations

import argparse
import re
import sys
from dataclasses import dataclass
from pathlib import Path

from mcap.exceptions import McapError
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader
from rosbags.rosbag2.metadata import parse_qos
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from hsa_bag.bagio import BagError
from hsa_bag.storage import METADATA, SplitFile, Topic, merge_info, read_metadata, write_metadata


@dataclass(frozen=True)
class Recovered:
    """One completed file and the number of messages it holds (0: nothing was flushed; the file was
    removed)."""

    file: Path
    messages: int


@dataclass
class Salvage:
    """The records of an MCAP file up to its first incomplete record."""

    schemas: dict[int, Schema]
    channels: dict[int, Channel]
    messages: list[Message]


def salvage(path: Path) -> Salvage:
    """Read ``path`` record by record until its end or its first incomplete record."""
    found = Salvage({}, {}, [])
    with open(path, "rb") as handle:
        try:
            for record in StreamReader(handle).records:
                if isinstance(record, Schema):
                    found.schemas[record.id] = record
                elif isinstance(record, Channel):
                    found.channels[record.id] = record
                elif isinstance(record, Message):
                    found.messages.append(record)
        except (McapError, ValueError, EOFError):
            pass  # the killed writer's last, partly written record (EndOfFile is an McapError)
    return found


def _split_index(path: Path) -> tuple[int, str]:
    """Sort key: the split number k of ``<name>_<k>.mcap``, then the name."""
    match = re.search(r"_(\d+)$", path.stem)
    return (int(match.group(1)) if match else -1, path.name)


def _rewrite(found: Salvage, directory: Path, stem: str, custom_data: dict[str, str]) -> dict:
    """Write the salvaged messages into a complete ``<directory>/<stem>.mcap``; return its bag
    information."""
    store = get_typestore(Stores.EMPTY)
    for schema in found.schemas.values():
        store.register(get_types_from_msg(schema.data.decode("utf8"), schema.name))
    split = SplitFile(directory, stem, custom_data)
    connections = {
        cid: split.add_connection(
            Topic(
                ch.topic,
                found.schemas[ch.schema_id].name,
                parse_qos(ch.metadata.get("offered_qos_profiles", "[]")),
            ),
            store,
        )
        for cid, ch in found.channels.items()
    }
    for message in found.messages:
        split.write(connections[message.channel_id], message.log_time, message.data)
    return split.close()


def recover_bag(path: Path) -> list[Recovered]:
    """Complete every unlisted MCAP file of bag directory ``path`` and list it in metadata.yaml (see
    module doc)."""
    if not path.is_dir():
        raise BagError(f"{path}: not a bag directory")
    info = read_metadata(path) if (path / METADATA).is_file() else None
    listed = set(info["relative_file_paths"]) if info else set()
    custom_data = dict(info.get("custom_data") or {}) if info else {}
    results = []
    for file in sorted((p for p in path.glob("*.mcap") if p.name not in listed), key=_split_index):
        aside = file.with_name(file.name + ".truncated")
        file.rename(aside)
        found = salvage(aside)
        if found.messages:
            info = merge_info(info, _rewrite(found, path, file.stem, custom_data))
            write_metadata(path, info)
        aside.unlink()
        results.append(Recovered(file, len(found.messages)))
    return results


def main(argv: list[str] | None = None) -> int:
    """Console script ``bag_recover``."""
    parser = argparse.ArgumentParser(prog="bag_recover", description=__doc__.split("\n\n")[0])
    parser.add_argument("bags", nargs="+", type=Path, help="bag directories")
    args = parser.parse_args(argv)
    status = 0
    for bag in args.bags:
        try:
            results = recover_bag(bag)
        except BagError as exc:
            print(f"bag_recover: {exc}", file=sys.stderr)
            status = 2
            continue
        if not results:
            print(f"{bag}: every file is complete and listed; nothing to do")
        for result in results:
            what = (
                f"completed with {result.messages} messages"
                if result.messages
                else "held no message; removed"
            )
            print(f"{result.file}: {what}")
    return status


if __name__ == "__main__":
    sys.exit(main())
