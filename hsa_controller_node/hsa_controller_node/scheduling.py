"""Real-time scheduling of the controller process (parameter ``realtime_priority``,
docs/nodes/hsa_controller_node.md "Real-time priority"): every thread under SCHED_RR at one fixed
priority, so that busy processes on the machine cannot keep the tick, the executor or the
middleware's receive threads waiting for a CPU.

``refusal(priority)`` asks the OS on a short-lived thread whether it grants SCHED_RR at ``priority``
to this process (CAP_SYS_NICE, or an RLIMIT_RTPRIO of at least ``priority``, in a cgroup allowed
real-time time) and returns why not; ``apply(priority)`` then switches every thread of the process
(``apply(0)``: back to the normal policy). Threads created later inherit the policy of the thread
that creates them (glibc's default PTHREAD_INHERIT_SCHED). Linux only.
"""

from __future__ import annotations

import os
import threading

from hsa_common.runner import each_thread

POLICY = os.SCHED_RR


def describe(priority: int) -> str:
    """The scheduling ``priority`` stands for, in words (0: the normal time-sharing policy)."""
    return f"SCHED_RR priority {priority}" if priority > 0 else "normal (SCHED_OTHER)"


def refusal(priority: int) -> str | None:
    """Why the OS refuses SCHED_RR at ``priority`` (1..99) to this process ("is refused by the OS:
    ..."), or None when it grants it."""
    result: list[OSError] = []

    def probe() -> None:
        try:
            os.sched_setscheduler(0, POLICY, os.sched_param(priority))  # this thread only
        except OSError as exc:
            result.append(exc)

    thread = threading.Thread(target=probe, name="rt-probe")
    thread.start()
    thread.join()
    if not result:
        return None
    return (
        f"is refused by the OS: {describe(priority)} ({result[0].strerror}); grant the node "
        f"CAP_SYS_NICE or an rtprio limit of at least {priority} (e.g. "
        "/etc/security/limits.conf), or set it to 0"
    )


def apply(priority: int) -> None:
    """Put every thread of this process under SCHED_RR at ``priority`` (0: under the normal
    SCHED_OTHER). Raises OSError when the OS refuses (see ``refusal``)."""
    policy, param = (POLICY if priority > 0 else os.SCHED_OTHER), os.sched_param(priority)
    each_thread(lambda tid: os.sched_setscheduler(tid, policy, param))
