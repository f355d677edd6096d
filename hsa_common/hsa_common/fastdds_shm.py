"""Fast DDS shared-memory files in /dev/shm: which a process uses, and removal of those no live
process uses.

Fast DDS's shared-memory transport (the default for ROS 2 processes on one machine) creates, per
participant, a segment ``fastrtps_<16 hex digits>`` with its lock file ``…_el``, and per port a
segment ``fastrtps_port<N>``, a lock file ``…_el`` (one reader) or ``…_sl`` (shared readers) and a
POSIX semaphore ``sem.fastrtps_port<N>_mutex``. The owner holds an ``flock`` on each lock file while
it lives and removes its files when the participant is destroyed; a process that dies without that
(SIGKILL, a crash) leaves them behind.

:func:`remove_unused` removes a group of these files (segment, lock files, semaphore) only when all
of these hold:

* a group with a lock file: no live process has a lock file of it open (``/proc/*/fd``; also a
  process between creating its lock file and locking it) and no lock is held (Fast DDS's own test,
  as ``fastdds shm clean``: a live owner holds its lock). Peers may still map a dead owner's
  segment: Fast DDS lets them go;
* a group without a lock file (a port segment or semaphore whose reader has gone): no live process
  maps or has open any of its files (``/proc/*/maps``, ``/proc/*/fd``), e.g. a process that writes
  to the port;
* every file of the group is older than ``grace`` seconds (a file created after the scan of /proc);
* for a port, its semaphore could be taken without waiting (Fast DDS opens and creates ports holding
  it).

Files of other users are left alone (only their owner may remove them from /dev/shm anyway).
"""

from __future__ import annotations

import ctypes
import errno
import fcntl
import os
import re
import time
from collections import defaultdict
from pathlib import Path

SHM_DIR = Path("/dev/shm")
GRACE = 2.0
"""[s] youngest age of a file that may be removed: the scan of /proc does not see a file created
after it."""
_MEMBER = re.compile(r"^(?:sem\.)?(fastrtps_(?:port\d{1,5}|[0-9a-f]{16}))(_el|_sl|_mutex)?$")


def group_of(name: str) -> str | None:
    """The group a Fast DDS file belongs to (``fastrtps_<id>`` or ``fastrtps_port<N>``); None for
    other files."""
    member = _MEMBER.match(name)
    return member.group(1) if member else None


def owned_by(pid: int | str, directory: Path = SHM_DIR) -> set[str]:
    """The groups whose lock file process ``pid`` holds open: its participant's segment and the
    ports it reads."""
    return {group_of(name) for name in used_by(pid, directory) if name.endswith(("_el", "_sl"))}


def used_by(pid: int | str, directory: Path = SHM_DIR) -> set[str]:
    """Names of the Fast DDS files in ``directory`` that process ``pid`` maps or has open (empty if
    it cannot be read)."""
    names: set[str] = set()
    prefix = f"{directory}/"
    try:
        with open(f"/proc/{pid}/maps") as maps:
            for line in maps:
                at = line.find(prefix)
                if at >= 0:
                    names.add(line[at + len(prefix) :].rstrip("\n").removesuffix(" (deleted)"))
        for fd in os.listdir(f"/proc/{pid}/fd"):
            try:
                target = os.readlink(f"/proc/{pid}/fd/{fd}")
            except OSError:
                continue
            if target.startswith(prefix):
                names.add(target[len(prefix) :].removesuffix(" (deleted)"))
    except OSError:
        pass  # the process ended, or is not ours
    return {name for name in names if _MEMBER.match(name)}


def in_use(directory: Path = SHM_DIR) -> set[str]:
    """Names of the Fast DDS files in ``directory`` that any live process maps or has open."""
    names: set[str] = set()
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            names |= used_by(entry, directory)
    return names


def owned(directory: Path = SHM_DIR) -> set[str]:
    """The groups whose lock file a live process holds open."""
    return {group_of(name) for name in in_use(directory) if name.endswith(("_el", "_sl"))}


def remove_unused(grace: float = GRACE, directory: Path = SHM_DIR) -> list[str]:
    """Remove the Fast DDS file groups no live process uses (rules in the module docstring); the
    names removed."""
    try:
        entries = os.listdir(directory)
    except OSError:
        return []
    groups: dict[str, list[str]] = defaultdict(list)
    for name in entries:
        base = group_of(name)
        if base is not None:
            groups[base].append(name)
    used = in_use(directory)
    removed: list[str] = []
    for base, names in groups.items():
        locks = [directory / name for name in names if name.endswith(("_el", "_sl"))]
        paths = [directory / name for name in names]
        if used.intersection(path.name for path in locks or paths) or not _old_and_ours(
            paths, grace
        ):
            continue
        with _PortMutex(base) as free:
            if not free or any(_locked(lock) for lock in locks):
                continue
            for name in sorted(names, key=lambda n: n.startswith("sem.")):  # the semaphore last
                try:
                    os.remove(directory / name)
                    removed.append(name)
                except FileNotFoundError:
                    pass
    return removed


def _old_and_ours(paths: list[Path], grace: float) -> bool:
    """Every file is ours and older than ``grace`` seconds."""
    newest = time.time() - grace
    for path in paths:
        try:
            stat = os.stat(path)
        except FileNotFoundError:
            continue
        if stat.st_uid != os.getuid() or max(stat.st_mtime, stat.st_ctime) > newest:
            return False
    return True


def _locked(path: Path) -> bool:
    """Whether another process holds an flock on the lock file (Fast DDS: its owner is alive)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except FileNotFoundError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return True
    finally:
        os.close(fd)  # closing releases our lock
    return False


class _PortMutex:
    """The port's semaphore ``sem.<base>_mutex`` taken without waiting (true also when there is
    none, or for a participant segment, which has none)."""

    def __init__(self, base: str) -> None:
        self._name = f"/{base}_mutex".encode() if "_port" in base else None
        self._sem: int | None = None
        self._libc = ctypes.CDLL(None, use_errno=True) if self._name else None

    def __enter__(self) -> bool:
        if self._libc is None:
            return True
        self._libc.sem_open.restype = ctypes.c_void_p
        sem = self._libc.sem_open(self._name, 0)
        if not sem:  # SEM_FAILED is NULL in glibc
            return ctypes.get_errno() == errno.ENOENT
        if self._libc.sem_trywait(ctypes.c_void_p(sem)) != 0:
            self._libc.sem_close(ctypes.c_void_p(sem))
            return False
        self._sem = sem
        return True

    def __exit__(self, *_exc: object) -> None:
        if self._sem is not None:
            self._libc.sem_post(ctypes.c_void_p(self._sem))
            self._libc.sem_close(ctypes.c_void_p(self._sem))
