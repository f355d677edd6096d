"""The one place that sets the ROS 2 process environment of every hsa-ros entry point (standard
library only: no rclpy, no JAX, so the launcher and test sessions load it cheaply).

Project rule (toolchain.md, top): every ROS process runs with
``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``, a run-specific ``ROS_DOMAIN_ID`` and
``RMW_IMPLEMENTATION`` unset, so that no DDS discovery traffic ever leaves the machine and
concurrent runs do not see each other. Test sessions, launchers, benchmarks and node ``main()``
functions all call into this module before ``rclpy`` is initialised or any child process is spawned.

A ``ROS_DOMAIN_ID`` the user set is theirs: entry points run on it, or refuse it in one line (exit
2) before anything starts; it is never replaced. Without one, a run reserves a domain of its own.
Test sessions always reserve one.
"""

from __future__ import annotations

import fcntl
import os
import sys
import tempfile
import warnings
from pathlib import Path
from typing import IO, MutableMapping, NoReturn

DISCOVERY_RANGE = "LOCALHOST"
DOMAIN_MIN, DOMAIN_MAX = 1, 101
"""Domains reserved for a run that has none: below Linux's ephemeral ports (docs/launch.md); 0 is
left to interactive use."""
USER_DOMAINS = (range(0, 102), range(215, 233))
"""Domains a user may set: those the ROS 2 docs give as clear of Linux's default ephemeral ports
(32768-60999) for Fast DDS's ports 7400 + 250 * domain + ...; 232 is the last whose ports fit in 16
bits (docs/launch.md)."""
_LOCK_DIR = Path(tempfile.gettempdir()) / "hsa_ros_domains"
# held open for the life of the process that reserved the domain
_domain_lock: IO[str] | None = None


class DomainIdError(ValueError):
    """A ROS_DOMAIN_ID this project will not run on; the message is one line naming the value."""


def parse_domain_id(text: str) -> int:
    """Return the domain a ``ROS_DOMAIN_ID`` value names, or raise :class:`DomainIdError`.

    Only plain decimal numbers in :data:`USER_DOMAINS` are taken: rcl reads the value with
    ``strtoul(.., 0)``, so ``010`` would be octal 8, ``1e2`` would be 1, and ``-1``, ``""`` or 2**32
    end up as domain 0.
    """
    shown = f"ROS_DOMAIN_ID={text!r}"
    if not text.isascii() or not text.isdigit():
        raise DomainIdError(
            f"{shown} is not a domain ID: give a decimal integer in 0..101 or 215..232, or unset it"
        )
    if len(text) > 1 and text.startswith("0"):
        raise DomainIdError(
            f"{shown} is ambiguous (ROS reads a leading 0 as octal): write it without the 0"
        )
    domain = int(text)
    if not any(domain in allowed for allowed in USER_DOMAINS):
        raise DomainIdError(
            f"{shown} is outside 0..101 and 215..232: its DDS ports "
            + ("overlap Linux's ephemeral ports 32768-60999" if domain <= 214 else "exceed 65535")
        )
    return domain


def _lock(domain: int) -> IO[str] | None:
    """Take the machine-wide lock of ``domain`` (writing our pid into it); None if another process
    holds it."""
    _LOCK_DIR.mkdir(parents=True, exist_ok=True)
    handle = open(_LOCK_DIR / f"{domain}.lock", "a+")  # noqa: SIM115 - kept open on purpose; "a+" keeps a holder's pid
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        handle.close()
        return None
    handle.truncate(0)
    handle.write(str(os.getpid()))
    handle.flush()
    return handle


def reserve_domain_id() -> int:
    """Reserve a ROS domain ID no other hsa-ros run on this machine holds (an flock per ID, released
    at exit)."""
    global _domain_lock
    start = os.getpid() % (DOMAIN_MAX - DOMAIN_MIN + 1)
    for k in range(DOMAIN_MAX - DOMAIN_MIN + 1):
        domain = DOMAIN_MIN + (start + k) % (DOMAIN_MAX - DOMAIN_MIN + 1)
        handle = _lock(domain)
        if handle is not None:
            _domain_lock = handle
            return domain
    raise RuntimeError(
        f"all ROS domain IDs {DOMAIN_MIN}..{DOMAIN_MAX} are in use by other hsa-ros runs"
    )


def claim_user_domain(domain: int) -> None:
    """Hold the lock of the user's ``domain`` (so no run reserves it); if another hsa-ros run holds
    it, say so on stderr in one line — the user's choice stands and the two graphs will see each
    other's topics."""
    global _domain_lock
    handle = _lock(domain)
    if handle is not None:
        _domain_lock = handle
        return
    holder = (_LOCK_DIR / f"{domain}.lock").read_text().strip() or "?"
    if holder == str(os.getpid()):
        return  # claimed by an earlier call in this process
    print(
        f"[hsa-ros] warning: ROS_DOMAIN_ID={domain} is also in use by another hsa-ros run (pid "
        f"{holder}): the two graphs will exchange messages; unset ROS_DOMAIN_ID to get a domain of "
        "this run's own",
        file=sys.stderr,
        flush=True,
    )


def ros_environment(
    base: MutableMapping[str, str] | None = None, domain_id: int | None = None
) -> dict[str, str]:
    """Return a copy of ``base`` (default: os.environ) made safe for ROS processes of this project.

    The domain ID is, in order: the explicit ``domain_id``; the ``ROS_DOMAIN_ID`` set in ``base`` —
    by an hsa-ros parent (marked by ``HSA_ROS_ENV=1``), or by the user (:func:`claim_user_domain`);
    a freshly reserved one. A set ``ROS_DOMAIN_ID`` that :func:`parse_domain_id` refuses raises
    :class:`DomainIdError`: it is never replaced.
    """
    env = dict(os.environ if base is None else base)
    if domain_id is None:
        if "ROS_DOMAIN_ID" in env:
            domain_id = parse_domain_id(env["ROS_DOMAIN_ID"])
            if env.get("HSA_ROS_ENV") != "1":
                claim_user_domain(domain_id)
        else:
            domain_id = reserve_domain_id()
    elif not any(domain_id in allowed for allowed in USER_DOMAINS):
        raise ValueError(f"domain_id must be in 0..101 or 215..232, got {domain_id}")
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = DISCOVERY_RANGE
    env["ROS_DOMAIN_ID"] = str(domain_id)
    env["HSA_ROS_ENV"] = "1"
    env.pop("RMW_IMPLEMENTATION", None)
    env.pop("ROS_LOCALHOST_ONLY", None)  # deprecated; it would override the discovery range
    env.pop("ROS_STATIC_PEERS", None)
    prefixes = [p for p in env.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    if sys.prefix not in prefixes:
        # the venv is the ROS install prefix (ament index of the wheels and hsa_msgs)
        prefixes.append(sys.prefix)
    env["AMENT_PREFIX_PATH"] = os.pathsep.join(prefixes)
    return env


def refuse(exc: DomainIdError) -> NoReturn:
    """End an entry point that was given a bad ROS_DOMAIN_ID: one line on stderr, exit status 2,
    nothing started."""
    print(f"{Path(sys.argv[0]).name}: refusing to start: {exc}", file=sys.stderr, flush=True)
    raise SystemExit(2)


def apply(domain_id: int | None = None) -> int:
    """Apply :func:`ros_environment` to this process (call before ``rclpy.init``); return the domain
    ID.

    For entry points: a set ``ROS_DOMAIN_ID`` that :func:`parse_domain_id` refuses ends the process
    (:func:`refuse`).
    """
    try:
        env = ros_environment(domain_id=domain_id)
    except DomainIdError as exc:
        refuse(exc)
    os.environ.clear()
    os.environ.update(env)
    return int(env["ROS_DOMAIN_ID"])


def ensure_for_node() -> None:
    """Guard for node entry points: force LOCALHOST discovery and unset RMW_IMPLEMENTATION, warning
    if they were off.

    A node started by hand without the project environment keeps its ROS_DOMAIN_ID (0 if unset), but
    never sends discovery traffic beyond the host; a set ROS_DOMAIN_ID that :func:`parse_domain_id`
    refuses ends the process (:func:`refuse`) instead of leaving rcl to read it as another domain.
    """
    if "ROS_DOMAIN_ID" in os.environ:
        try:
            parse_domain_id(os.environ["ROS_DOMAIN_ID"])
        except DomainIdError as exc:
            refuse(exc)
    problems = []
    if os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE") != DISCOVERY_RANGE:
        problems.append(
            f"ROS_AUTOMATIC_DISCOVERY_RANGE was {os.environ.get('ROS_AUTOMATIC_DISCOVERY_RANGE')!r}"
        )
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = DISCOVERY_RANGE
    for name in ("RMW_IMPLEMENTATION", "ROS_LOCALHOST_ONLY"):
        if name in os.environ:
            problems.append(f"{name} was set")
            del os.environ[name]
    if problems:
        warnings.warn(
            "hsa-ros forces local-only DDS discovery: " + "; ".join(problems),
            RuntimeWarning,
            stacklevel=2,
        )
