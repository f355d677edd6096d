"""The one place that sets the ROS 2 process environment of every hsa-ros entry point (standard library only: no rclpy,
no JAX, so the launcher and test sessions load it cheaply).

Project rule (toolchain.md, top): every ROS process runs with ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``, a
run-specific ``ROS_DOMAIN_ID`` and ``RMW_IMPLEMENTATION`` unset, so that no DDS discovery traffic ever leaves the
machine and concurrent runs do not see each other. Test sessions, launchers, benchmarks and node ``main()``
functions all call into this module before ``rclpy`` is initialised or any child process is spawned.
"""

from __future__ import annotations

import fcntl
import os
import sys
import tempfile
import warnings
from pathlib import Path
from typing import IO, MutableMapping

DISCOVERY_RANGE = "LOCALHOST"
DOMAIN_MIN, DOMAIN_MAX = 1, 101  # 0..101 is the safe range for Fast DDS ports; 0 is left to interactive use
_LOCK_DIR = Path(tempfile.gettempdir()) / "hsa_ros_domains"
_domain_lock: IO[str] | None = None  # held open for the life of the process that reserved the domain


def reserve_domain_id() -> int:
    """Reserve a ROS domain ID no other hsa-ros run on this machine holds (an flock per ID, released at exit)."""
    global _domain_lock
    _LOCK_DIR.mkdir(parents=True, exist_ok=True)
    start = os.getpid() % (DOMAIN_MAX - DOMAIN_MIN + 1)
    for k in range(DOMAIN_MAX - DOMAIN_MIN + 1):
        domain = DOMAIN_MIN + (start + k) % (DOMAIN_MAX - DOMAIN_MIN + 1)
        handle = open(_LOCK_DIR / f"{domain}.lock", "w")  # noqa: SIM115 - kept open on purpose
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            handle.close()
            continue
        _domain_lock = handle
        return domain
    raise RuntimeError(f"all ROS domain IDs {DOMAIN_MIN}..{DOMAIN_MAX} are in use by other hsa-ros runs")


def ros_environment(
    base: MutableMapping[str, str] | None = None, domain_id: int | None = None
) -> dict[str, str]:
    """Return a copy of ``base`` (default: os.environ) made safe for ROS processes of this project.

    The domain ID is, in order: the explicit ``domain_id``; the one already set in ``base`` by an hsa-ros parent
    (marked by ``HSA_ROS_ENV=1``); a freshly reserved one.
    """
    env = dict(os.environ if base is None else base)
    if domain_id is None:
        inherited = env.get("ROS_DOMAIN_ID") if env.get("HSA_ROS_ENV") == "1" else None
        domain_id = int(inherited) if inherited else reserve_domain_id()
    if not 0 <= domain_id <= DOMAIN_MAX:
        raise ValueError(f"ROS_DOMAIN_ID must be in 0..{DOMAIN_MAX}, got {domain_id}")
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = DISCOVERY_RANGE
    env["ROS_DOMAIN_ID"] = str(domain_id)
    env["HSA_ROS_ENV"] = "1"
    env.pop("RMW_IMPLEMENTATION", None)
    env.pop("ROS_LOCALHOST_ONLY", None)  # deprecated; it would override the discovery range
    env.pop("ROS_STATIC_PEERS", None)
    prefixes = [p for p in env.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    if sys.prefix not in prefixes:
        prefixes.append(sys.prefix)  # the venv is the ROS install prefix (ament index of the wheels and hsa_msgs)
    env["AMENT_PREFIX_PATH"] = os.pathsep.join(prefixes)
    return env


def apply(domain_id: int | None = None) -> int:
    """Apply :func:`ros_environment` to this process (call before ``rclpy.init``); return the domain ID."""
    env = ros_environment(domain_id=domain_id)
    os.environ.clear()
    os.environ.update(env)
    return int(env["ROS_DOMAIN_ID"])


def ensure_for_node() -> None:
    """Guard for node entry points: force LOCALHOST discovery and unset RMW_IMPLEMENTATION, warning if they were off.

    A node started by hand without the project environment keeps its ROS_DOMAIN_ID (0 if unset), but never sends
    discovery traffic beyond the host.
    """
    problems = []
    if os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE") != DISCOVERY_RANGE:
        problems.append(f"ROS_AUTOMATIC_DISCOVERY_RANGE was {os.environ.get('ROS_AUTOMATIC_DISCOVERY_RANGE')!r}")
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = DISCOVERY_RANGE
    for name in ("RMW_IMPLEMENTATION", "ROS_LOCALHOST_ONLY"):
        if name in os.environ:
            problems.append(f"{name} was set")
            del os.environ[name]
    if problems:
        warnings.warn(
            "hsa-ros forces local-only DDS discovery: " + "; ".join(problems), RuntimeWarning, stacklevel=2
        )
