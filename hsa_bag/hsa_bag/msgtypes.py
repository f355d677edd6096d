"""Message definitions for writing bags: the rosbags Jazzy typestore plus interface packages
installed on the system.

A type that the Jazzy store lacks (``hsa_msgs/msg/ControllerInfo``) is registered from the ``.msg``
text its package installs (ament index: ``<prefix>/share/<pkg>/msg/*.msg``; without
AMENT_PREFIX_PATH, the running Python's prefix, which is the ROS install prefix of the project
venv). All messages of the package are registered together, and packages referenced by nested fields
are registered in turn, so the schema rosbags writes into the bag is complete. The resulting RIHS01
hashes equal the rosidl ones (toolchain.md §6). :func:`message_class` imports the generated Python
class of a type for (raw) subscriptions and publishers.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Iterator
from pathlib import Path

from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
from rosbags.interfaces import Nodetype
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore


class UnknownTypeError(LookupError):
    """A message type is neither a standard Jazzy type nor defined by an installed package's .msg
    files."""


def _named_types(field: tuple[Nodetype, object]) -> Iterator[str]:
    """Names of the message types a rosbags field definition refers to (through arrays and
    sequences)."""
    kind, detail = field
    if kind == Nodetype.NAME:
        yield str(detail)
    elif kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
        yield from _named_types(detail[0])  # type: ignore[index]


def _share_directory(package: str) -> Path | None:
    """The installed share directory of ``package`` with a msg/ folder, or None."""
    try:
        share = Path(get_package_share_directory(package))
    except (PackageNotFoundError, ValueError, OSError):  # OSError: AMENT_PREFIX_PATH unset
        share = Path(sys.prefix, "share", package)
    return share if (share / "msg").is_dir() else None


def message_class(msgtype: str) -> type:
    """The generated Python class of ``pkg/msg/Type`` (ImportError/AttributeError if it is not
    installed)."""
    package, kind, name = msgtype.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), name)


class TypeRegistry:
    """A rosbags typestore that learns installed interface packages on demand."""

    def __init__(self) -> None:
        self.store: Typestore = get_typestore(Stores.ROS2_JAZZY)
        self._packages: set[str] = set()

    def ensure(self, msgtype: str) -> None:
        """Make ``msgtype`` (``pkg/msg/Type``) and every type it nests known; raise UnknownTypeError
        naming the gap."""
        pending = [msgtype]
        seen: set[str] = set()
        while pending:
            name = pending.pop()
            if name in seen:
                continue
            seen.add(name)
            if name not in self.store.fielddefs:
                self._register_package(name)
            if name not in self.store.fielddefs:
                raise UnknownTypeError(
                    f"type {name} is not defined by the package's installed .msg files"
                )
            _, fields = self.store.fielddefs[name]
            pending += [nested for _, field in fields for nested in _named_types(field)]

    def _register_package(self, msgtype: str) -> None:
        """Register every .msg of the package of ``msgtype`` from its installed share directory."""
        package = msgtype.split("/", 1)[0]
        if package in self._packages:
            return
        share = _share_directory(package)
        if share is None:
            raise UnknownTypeError(
                f"type {msgtype} is not a standard Jazzy type and package {package} is not "
                "installed"
            )
        types = {}
        for path in sorted((share / "msg").glob("*.msg")):
            types.update(
                get_types_from_msg(path.read_text(encoding="utf8"), f"{package}/msg/{path.stem}")
            )
        self.store.register(types)
        self._packages.add(package)
