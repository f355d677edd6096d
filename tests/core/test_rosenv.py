"""A user's ROS_DOMAIN_ID is run on or refused in one line, never replaced (hsa_common.rosenv; no
ROS needed)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from hsa_common import rosenv

APPLY = "from hsa_common import rosenv; print(rosenv.apply(), flush=True)"
HOLD = APPLY + "; import time; time.sleep(60)"


def user_env(domain: str, locks: Path | None = None) -> dict[str, str]:
    """The environment of a user's shell that set ROS_DOMAIN_ID (no hsa-ros parent); ``locks``: a
    private TMPDIR, so the domain locks are this test's alone (other sessions on this machine hold
    theirs in the real one)."""
    env = {k: v for k, v in os.environ.items() if k not in ("HSA_ROS_ENV", "ROS_DOMAIN_ID")}
    env["ROS_DOMAIN_ID"] = domain
    if locks is not None:
        env["TMPDIR"] = str(locks)
    return env


@pytest.mark.parametrize("text", ["0", "7", "101", "215", "232"])
def test_valid_domain_ids_are_taken(text: str) -> None:
    assert rosenv.parse_domain_id(text) == int(text)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("150", "overlap Linux's ephemeral ports"),
        ("214", "overlap Linux's ephemeral ports"),
        ("102", "ephemeral"),
        ("233", "exceed 65535"),
        ("4294967296", "exceed 65535"),
        ("-1", "not a domain ID"),
        ("", "not a domain ID"),
        ("1e2", "not a domain ID"),
        (" 7", "not a domain ID"),
        ("0x10", "not a domain ID"),
        ("\u0663", "not a domain ID"),
        ("010", "octal"),
    ],
)
def test_invalid_domain_ids_are_refused(text: str, message: str) -> None:
    with pytest.raises(rosenv.DomainIdError, match=message):
        rosenv.parse_domain_id(text)


def test_ros_environment_keeps_an_inherited_domain_and_refuses_a_bad_one() -> None:
    assert (
        rosenv.ros_environment({"HSA_ROS_ENV": "1", "ROS_DOMAIN_ID": "42"})["ROS_DOMAIN_ID"] == "42"
    )
    with pytest.raises(rosenv.DomainIdError):
        rosenv.ros_environment({"HSA_ROS_ENV": "1", "ROS_DOMAIN_ID": "150"})


@pytest.mark.parametrize("domain", ["150", "-1", "", "1e2", "4294967296"])
def test_entry_point_refuses_a_bad_user_domain_in_one_line(domain: str) -> None:
    """rosenv.apply, which every entry point calls first: exit 2, one line naming the value, no
    traceback."""
    done = subprocess.run(
        [sys.executable, "-c", APPLY],
        env=user_env(domain),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 2 and done.stdout == "", done.stderr
    assert done.stderr.count("\n") == 1 and f"ROS_DOMAIN_ID={domain!r}" in done.stderr, done.stderr
    assert "refusing to start" in done.stderr and "Traceback" not in done.stderr


def test_entry_point_runs_on_the_user_domain_and_warns_when_another_run_holds_it(
    tmp_path: Path,
) -> None:
    """The first run holds the user's domain 7; a second run on it is told so in one line and still
    runs on it."""
    first = subprocess.Popen(
        [sys.executable, "-c", HOLD],
        env=user_env("7", tmp_path),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert first.stdout.readline() == "7\n"
        second = subprocess.run(
            [sys.executable, "-c", APPLY],
            env=user_env("7", tmp_path),
            capture_output=True,
            text=True,
            timeout=60,
        )
    finally:
        first.kill()
        _, first_err = first.communicate()
    assert first_err == ""  # the domain was free: no warning
    assert second.returncode == 0 and second.stdout == "7\n", second.stderr
    assert second.stderr.count("\n") == 1, second.stderr
    assert (
        f"ROS_DOMAIN_ID=7 is also in use by another hsa-ros run (pid {first.pid})" in second.stderr
    )


def test_a_node_started_by_hand_refuses_a_bad_domain() -> None:
    """hsa_common.runner calls ensure_for_node before rclpy.init: rcl would run on 150 and read '-1'
    as domain 0."""
    code = "from hsa_common import rosenv; rosenv.ensure_for_node(); print('started')"
    for domain in ("150", "-1"):
        done = subprocess.run(
            [sys.executable, "-c", code],
            env=user_env(domain),
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert done.returncode == 2 and "started" not in done.stdout, done.stderr
        assert done.stderr.count("\n") == 1 and "refusing to start" in done.stderr, done.stderr
    done = subprocess.run(
        [sys.executable, "-c", code], env=user_env("7"), capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 0 and done.stdout == "started\n", done.stderr


def test_reservation_skips_a_domain_a_user_run_holds(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A user run on domain d in 1..101 holds d's lock, so a run that reserves its domain does not
    land on it."""
    span = rosenv.DOMAIN_MAX - rosenv.DOMAIN_MIN + 1
    # where reserve_domain_id starts in this process
    first_choice = rosenv.DOMAIN_MIN + os.getpid() % span
    user = subprocess.Popen(
        [sys.executable, "-c", HOLD],
        env=user_env(str(first_choice), tmp_path),
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert user.stdout.readline() == f"{first_choice}\n"
        monkeypatch.setattr(rosenv, "_LOCK_DIR", tmp_path / "hsa_ros_domains")
        # keeps this session's own lock handle alive
        monkeypatch.setattr(rosenv, "_domain_lock", None)
        assert (
            rosenv.reserve_domain_id()
            == rosenv.DOMAIN_MIN + (first_choice - rosenv.DOMAIN_MIN + 1) % span
        )
    finally:
        user.kill()
        user.wait()
