"""Entry-point runner shared by every hsa-ros node: environment guard, init, spin, and a shutdown
that always runs.

``run(MyNode)`` ends the process with its exit code: 0 after a stop signal or when the node shuts
its context down, 2 when the parameters are refused at start (the error names the parameter, or the
parameter file rcl cannot parse), 1 after an uncaught exception (which propagates) or when the
launcher that started it has already ended. In every case the node's ``on_shutdown()`` hook runs
before the process exits — the driver turns torque off there. ``run_nodes`` does the same for
several nodes in one process (:mod:`hsa_common.compose`).

Stop signals: SIGINT (Ctrl-C), SIGTERM, SIGHUP (terminal or ssh session closed) and SIGQUIT
(Ctrl-\\) all stop the node the same way; a SIGHUP ignored at start (``nohup``) stays ignored. A
stop signal that arrives while the node is still being created (parameter checks, JAX compilation)
ends the process at once with exit 0: construction never touches the hardware (the driver enables
torque from the executor), so there is nothing to stop yet; a signal the kernel handed to another
thread of the process is sent on to the main thread (:func:`watch_stop`). The node also stops when
the process that started it ends, even by SIGKILL: the kernel sends it SIGTERM then
(:mod:`hsa_common.parent_death`).

Executor: rclpy's C++ ``EventsExecutor`` by default (a third of the CPU of the Python
``SingleThreadedExecutor`` for our 40-200 Hz timers and 200 Hz streams; see
benchmarks/bench_graph.py), ``HSA_EXECUTOR=single`` selects the latter. The stop signals only set a
flag (rclpy's own handlers are off): a ``KeyboardInterrupt`` raised inside a callback would
interrupt it half-way — e.g. a bus transaction — and the events executor logs that as a fatal
callback error. In a process of neither the driver nor the simulator (no node ``stops_first``),
every thread drops to a lower CPU priority (``TEARDOWN_NICE``) after the ``on_shutdown`` hooks and
waits ``TEARDOWN_DELAY`` before the middleware teardown: when a whole graph stops at once on two
cores, the driver's torque-off and the simulator's bus answering it must not queue behind the other
nodes' teardown, nor behind the discovery work it sets off in every other process.

After its hook and rclpy's shutdown (which destroys the middleware participant, and so removes its
Fast DDS shared-memory files from /dev/shm) a node leaves with ``os._exit``, a refused one too: what
must persist is persisted by then, and the interpreter's own teardown (JAX/XLA) can outlast the
launcher's SIGTERM on a busy machine (docs/launch.md, "Teardown bounds"). rclpy's shutdown itself is
bounded (``TEARDOWN_LIMIT``): it can hang inside the middleware while holding the GIL, so past the
limit the node prints every thread's stack and a C-level timer ends it with its exit code
(:mod:`hsa_common.exit_deadline`).

Lockstep (parameter ``lockstep: true``, with ``use_sim_time``): the node joins the simulator's
barrier (:mod:`hsa_common.lockstep`) — the same executor runs one ready callback at a time
(``HSA_EXECUTOR=single``: :class:`~hsa_common.lockstep.LockstepExecutor`, rclpy's Python executor
with a lean wait) and, whenever none is ready, the node reports to the simulator. A node
can end the process with a code of its own by setting ``exit_code`` before it shuts its context
down (the simulator does, when a barrier times out).
"""

from __future__ import annotations

import faulthandler
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import NoReturn, Protocol, runtime_checkable

import rclpy
from rclpy._rclpy_pybind11 import RCLError
from rclpy.executors import (
    ConditionReachedException,
    Executor,
    ExternalShutdownException,
    ShutdownException,
    SingleThreadedExecutor,
    TimeoutException,
)
from rclpy.experimental import EventsExecutor
from rclpy.lifecycle import LifecycleNode
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from hsa_common import exit_deadline, lockstep, parent_death, rosenv, stacks
from hsa_common.middleware_errors import MiddlewareErrors
from hsa_common.parameters import ParameterValidationError
from hsa_core.sim.lockstep import ReportPacing

TEARDOWN_NICE = 5
"""Niceness added to every thread of a process that does not stop first, for its teardown: below the
driver's torque-off in a graph stop, but not starved (at 19 the launcher's SIGTERM escalation hit
every node on a busy machine; docs/launch.md, "Teardown bounds")."""
TEARDOWN_DELAY = 0.15
"""[s] wait of a process that does not stop first between its hooks and its middleware teardown:
longer than a graph stop's torque-off takes (< 100 ms, the requirement)."""
TASKS = "/proc/self/task"
SPIN_PERIOD = 0.02
"""[s] longest spin_once wait: bounds how late a stop request is noticed when no callback runs (<
100 ms torque-off)."""
TEARDOWN_LIMIT = 5.0
"""[s] longest wait for rclpy's teardown (destroy_node, shutdown) after the node's own: past it the
node prints every thread's stack and, ``TEARDOWN_DUMP`` later, ends with its exit code
(:mod:`hsa_common.exit_deadline`). It takes milliseconds, but can hang inside the middleware
(docs/launch.md, "Teardown bounds")."""
TEARDOWN_DUMP = 1.0
"""[s] time left for the stack dump before the deadline ends the process."""
STUCK_AFTER = 8.0
"""[s] after the first stop signal, a node still running prints every thread's stack (once) to
stderr: a stop takes well under a second, so by then it is stuck, and the launcher's SIGKILL (10 s
after its SIGINT with its default timeouts, as ros2 launch's) would otherwise leave no trace of
where."""

HANDLER_WAIT = 0.1
"""[s] how long the stop watch waits for the main thread to run the stop handler before sending it
the signal itself (:func:`watch_stop`)."""

# orders the stop watch's stack dump and the teardown's (one faulthandler timer)
_DUMP_LOCK = threading.Lock()
_TEARDOWN = threading.Event()  # set once the runner bounds rclpy's teardown
_STUCK_DUMP_AT: list[float] = []  # monotonic time of the stuck-stop dump, once armed


def run(node_factory: Callable[[], Node], name: str, args: list[str] | None = None) -> NoReturn:
    """Create the node with ``node_factory``, spin it until shutdown and end the process with its
    exit code (see the module docstring); only an uncaught exception leaves it."""
    return run_nodes([node_factory], name, args)


def run_nodes(
    node_factories: Sequence[Callable[[], Node]], name: str, args: list[str] | None = None
) -> NoReturn:
    """:func:`run` for several nodes in one process (:mod:`hsa_common.compose`): one context (one
    DDS participant), one executor; the nodes are created in order and their ``on_shutdown`` hooks
    run in that order; the exit code is the first non-zero ``exit_code`` of the nodes."""
    rosenv.ensure_for_node()
    stacks.enable()  # the launcher asks a stuck process where it is
    # before the SIGHUP handler: an ignored SIGHUP means nohup
    tie = parent_death.tie_to_parent(signal.SIGTERM)
    stopped = parent_death.StopFlag()  # the handler takes no lock (on_stop_signals)
    stop = stopped.signals
    starting = True

    def on_stop(signum: int, _frame: object) -> None:
        stopped.set(signum)
        if starting and len(stop) == 1:  # a second signal must not break the unwinding
            raise StopBeforeReady(signum)  # unwinds the node's construction: nothing is running yet

    parent_death.on_stop_signals(on_stop)
    watch_stop(stopped)
    logger = rclpy.logging.get_logger(name)
    if tie is parent_death.Tie.ORPHANED:
        logger.fatal(
            f"not starting: the launcher (PID {os.environ[parent_death.PARENT_ENV]}) has already "
            "ended"
        )
        _exit(1)
    nodes: list[Node] = []
    try:
        try:
            rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
        except RCLError as exc:  # malformed command line or parameter file: rcl names it
            logger.fatal(f"refusing to start: {exc}")
            _exit(2)
        try:
            for factory in node_factories:
                nodes.append(factory())
        except ParameterValidationError as exc:
            logger.fatal(f"refusing to start: {exc}")
            _shut_down(nodes)
            _bounded_teardown(nodes, 2)
            _exit(2)
        except BaseException:
            # a later node failed or a stop came: the nodes made so far stop first
            _shut_down(nodes)
            raise
        starting = False
    except StopBeforeReady:
        logger.info("stopped before ready")
        _bounded_teardown(nodes, 0)
        _exit(0)
    in_lockstep = any(lockstep.enabled(node) for node in nodes)
    participant = lockstep.Group(
        [
            lockstep.Participant(node)
            for node in nodes
            if lockstep.enabled(node)
            and not (isinstance(node, Coordinator) and node.lockstep_coordinator)
        ]
    )
    executor = make_executor(lockstep_spin=in_lockstep)
    for node in nodes:
        executor.add_node(node)
    errors = MiddlewareErrors(nodes[0])  # a malformed message: one throttled line per process
    failed = True  # until the spin ends in an orderly stop
    try:
        for node in nodes:  # start-up (parameter checks, JAX compilation) is complete
            node.get_logger().info("ready")
        if in_lockstep:
            spin_lockstep(executor, participant, stop, errors)
        while not stop and rclpy.ok():
            executor.spin_once(timeout_sec=SPIN_PERIOD)
            errors.check()
        failed = False
    except ExternalShutdownException:
        failed = False  # a node shut its context down (e.g. the sequencer's exit_on_finish)
    except (RCLError, RuntimeError):
        if rclpy.ok():
            raise
        failed = False
        # the context was shut down while a callback was publishing or a message was being taken
        # (rclpy raises RCLError or a pybind11 RuntimeError then): an orderly stop, not a failure
    finally:
        if rclpy.ok():
            participant.idle(leaving=True)
        _shut_down(nodes)
        if not any(isinstance(node, StopsFirst) and node.stops_first for node in nodes):
            # the driver's torque-off and the simulated bus go first in a graph stop
            lower_priority(TEARDOWN_NICE)
            time.sleep(TEARDOWN_DELAY)
        executor.shutdown(timeout_sec=1.0)
        _bounded_teardown(nodes, 1 if failed else exit_code(nodes))
    _exit(exit_code(nodes))


def _bounded_teardown(nodes: Sequence[Node], code: int) -> None:
    """Destroy ``nodes`` and shut rclpy down; the middleware's teardown may hang holding the GIL, so
    past ``TEARDOWN_LIMIT`` every thread's stack is printed and :mod:`hsa_common.exit_deadline` ends
    the process with ``code``. A stuck-stop dump still to come is not postponed by this one."""
    with _DUMP_LOCK:
        _TEARDOWN.set()  # from now on the stop watch leaves this dump alone
        now = time.monotonic()
        due = [at - now for at in _STUCK_DUMP_AT if at > now]
        faulthandler.dump_traceback_later(min([TEARDOWN_LIMIT, *due]))
    exit_deadline.arm(TEARDOWN_LIMIT + TEARDOWN_DUMP, code)
    for node in nodes:
        node.destroy_node()
        if isinstance(node, LifecycleNode):
            # the state machine holds the node handle; rclpy's destroy_node leaves it
            node._state_machine.destroy_when_not_in_use()
    rclpy.try_shutdown()
    faulthandler.cancel_dump_traceback_later()


def _exit(code: int) -> NoReturn:
    """End the process with ``code`` once the output is flushed, without the interpreter's teardown
    (JAX/XLA, which can outlast the launcher's SIGTERM on a busy machine): what must persist is
    persisted by then."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except OSError:
            # the terminal was closed (EIO) or the launcher is gone (EPIPE): nothing left to tell
            pass
    os._exit(code)


def _shut_down(nodes: Sequence[Node]) -> None:
    """Run the ``on_shutdown`` hook of each node already made (the driver turns torque off
    there)."""
    for node in nodes:
        if isinstance(node, ShutdownHook):
            node.on_shutdown()


def each_thread(action: Callable[[int], object]) -> None:
    """Call ``action(tid)`` for every thread of this process (Linux: /proc/self/task; elsewhere
    once, with 0: the calling thread); a thread that ended since the listing is skipped."""
    tids = [int(tid) for tid in os.listdir(TASKS)] if os.path.isdir(TASKS) else [0]
    for tid in tids:
        try:
            action(tid)
        except ProcessLookupError:
            pass


def lower_priority(niceness: int) -> None:
    """Add ``niceness`` to the nice value of every thread of this process (at most 19): on Linux a
    thread's nice value is its own, and ``os.nice`` changes only the calling thread's; the
    middleware's threads do the heavy part of a teardown. Threads created later inherit the nice
    value of the thread that creates them."""
    each_thread(
        lambda tid: os.setpriority(
            os.PRIO_PROCESS, tid, min(os.getpriority(os.PRIO_PROCESS, tid) + niceness, 19)
        )
    )


def exit_code(nodes: Sequence[Node]) -> int:
    """The first non-zero ``exit_code`` a node set (0 if none did)."""
    codes = (int(node.exit_code) for node in nodes if isinstance(node, ExitStatus))
    return next((code for code in codes if code), 0)


@runtime_checkable
class ShutdownHook(Protocol):
    """A node with work to do before rclpy's teardown on every stop (the driver: torque off)."""

    def on_shutdown(self) -> object: ...


@runtime_checkable
class ExitStatus(Protocol):
    """A node that sets its process's exit code (non-zero: the run failed)."""

    exit_code: int


@runtime_checkable
class StopsFirst(Protocol):
    """A node whose stop must not wait behind other nodes' teardown in a graph stop (the driver:
    torque off; the simulator: the bus that executes it); its process skips ``TEARDOWN_DELAY``."""

    stops_first: bool


@runtime_checkable
class Coordinator(Protocol):
    """A node that runs the lockstep barrier itself and so is not a participant of it."""

    lockstep_coordinator: bool


class StopBeforeReady(BaseException):
    """A stop signal arrived while the node was being created (a BaseException, like
    KeyboardInterrupt, so that no ``except Exception`` in the construction swallows it)."""


def spin_lockstep(
    executor: Executor,
    participant: lockstep.Reporter | None,
    stop: list[int],
    errors: MiddlewareErrors | None = None,
) -> None:
    """Run ready callbacks one at a time; when none is ready
    (:class:`hsa_core.sim.lockstep.ReportPacing`), report to the simulator (if a participant: one
    node's or a composed process's). ``errors`` (if given) is checked after each callback. The
    events executor takes :func:`spin_lockstep_events`."""
    if not isinstance(executor, Executor):
        return spin_lockstep_events(executor, participant, stop, errors)
    pacing = ReportPacing(period=SPIN_PERIOD)
    while not stop and rclpy.ok():
        try:
            handler, _, _ = executor.wait_for_ready_callbacks(timeout_sec=pacing.timeout())
        except TimeoutException:
            pacing.timed_out()
            if participant is not None:
                participant.idle()
            continue
        except (ShutdownException, ConditionReachedException):
            return
        pacing.ran()
        handler()
        if errors is not None:
            errors.check()
        if handler.exception() is not None:
            raise handler.exception()


def spin_lockstep_events(
    executor: object,
    participant: lockstep.Reporter | None,
    stop: list[int],
    errors: MiddlewareErrors | None = None,
) -> None:
    """:func:`spin_lockstep` on rclpy's events executor, whose ``spin_once`` runs at most one
    callback and says nothing of it: the process is idle once a ``spin_once`` ran no callback that
    can change a report (the participants' ``activity`` count did not move). A callback's exception
    leaves ``spin_once``."""
    pacing = ReportPacing(period=SPIN_PERIOD)
    while not stop:
        before = participant.activity if participant is not None else 0
        executor.spin_once(timeout_sec=pacing.timeout())  # type: ignore[attr-defined]
        if errors is not None:
            errors.check()
        if participant is not None and participant.activity != before:
            pacing.ran()
            continue
        if not rclpy.ok():  # a shutdown ends the executor's work: the next spin_once runs nothing
            return
        pacing.timed_out()
        if participant is not None:
            participant.idle()


def watch_stop(handled: parent_death.StopFlag) -> None:
    """Arm the stuck-stop report: a thread that learns of the first stop signal from the
    interpreter's wakeup fd, which the C-level handler writes even while the main thread is blocked
    in rcl or DDS and runs no Python. If the stop handler has not run (``handled``) within
    ``HANDLER_WAIT``, it sends the signal to the main thread: the kernel may give a process's signal
    to any of its threads, and a main thread asleep in a system call would then not run the handler
    until that call returns (a node's construction, for example)."""
    read_fd, write_fd = os.pipe()
    os.set_blocking(write_fd, False)
    signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)

    def watch() -> None:
        signum = os.read(read_fd, 1)[0]
        if signum in parent_death.STOP_SIGNALS and not handled.wait(HANDLER_WAIT):
            signal.pthread_kill(threading.main_thread().ident, signum)
        with _DUMP_LOCK:
            if not _TEARDOWN.is_set():  # else the teardown's dump is armed, no later than this
                faulthandler.dump_traceback_later(STUCK_AFTER, exit=False)
                _STUCK_DUMP_AT.append(time.monotonic() + STUCK_AFTER)

    threading.Thread(target=watch, name="stop-watch", daemon=True).start()


def make_executor(lockstep_spin: bool = False) -> Executor:
    """The executor named by HSA_EXECUTOR: 'events' (rclpy's C++ EventsExecutor, the default) or
    'single' (rclpy's Python executor; for a lockstep spin its lean variant,
    :class:`hsa_common.lockstep.LockstepExecutor`)."""
    kind = os.environ.get("HSA_EXECUTOR", "events")
    if kind == "events":
        return EventsExecutor()
    if kind == "single":
        return lockstep.LockstepExecutor() if lockstep_spin else SingleThreadedExecutor()
    raise ValueError(f"HSA_EXECUTOR must be 'events' or 'single', not {kind!r}")


def seconds(duration: object) -> float:
    """rclpy Duration (e.g. the difference of two rclpy Times) → float seconds."""
    return duration.nanoseconds * 1e-9  # type: ignore[attr-defined]
