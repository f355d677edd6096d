"""A stuck process's stacks, asked for by the launcher before it kills the process.

Why: a node that ignores SIGINT and SIGTERM is stuck, in native code holding the GIL or on a lock
its main thread waits for, and then no Python thread of its own may be able to report where (the
runner's timed dumps are armed from Python). The launcher sends :data:`SIGNAL` before SIGKILL:
:func:`enable` has made it print every Python thread's stack from the C signal handler
(``faulthandler.register``), which needs no GIL. The launcher adds what the kernel says of each
thread (:func:`kernel_view`: name, state, where it sleeps), which shows native waits the Python
stacks cannot.
"""

from __future__ import annotations

import faulthandler
import os
import signal
from pathlib import Path

SIGNAL = signal.SIGUSR1
"""The signal that asks a process started by the runner for its Python stacks (on stderr)."""


def enable() -> None:
    """Print every thread's Python stack to stderr when :data:`SIGNAL` arrives."""
    faulthandler.register(SIGNAL, all_threads=True)


def kernel_view(pid: int) -> list[str]:
    """One line per thread of ``pid``: thread id, name, state, and the kernel function it sleeps
    in (``wchan``) with its system call number (``syscall``); empty if the process is gone."""
    tasks = Path(f"/proc/{pid}/task")
    try:
        tids = sorted(int(tid) for tid in os.listdir(tasks))
    except OSError:
        return []
    lines = []
    for tid in tids:
        fields = {}
        for name in ("comm", "wchan", "syscall"):
            try:
                fields[name] = (tasks / str(tid) / name).read_text().strip()
            except OSError:
                fields[name] = "?"
        try:
            state = (tasks / str(tid) / "stat").read_text().rsplit(")", 1)[1].split()[0]
        except (OSError, IndexError):
            state = "?"
        syscall = fields["syscall"].split()[0] if fields["syscall"] != "?" else "?"
        lines.append(
            f"thread {tid} {fields['comm']!r} state {state} wchan {fields['wchan'] or '-'} "
            f"syscall {syscall}"
        )
    return lines
