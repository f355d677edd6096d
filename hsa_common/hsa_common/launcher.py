"""Run a ROS 2 YAML launch file (launch_scripts/*.launch.yaml) without ros2launch, which is not
installable here.

The same file works with ``ros2 launch <file>`` (launch 3.4 / launch_ros 0.26, Jazzy): every entry
is checked against the keys the real launch_yaml parser reads (``Unexpected key(s) found in 'node'``
there is a refusal here too), and the keys of that schema this launcher does not implement are
refused by name instead of being ignored. Implemented, with the same meaning:

* ``arg`` (name, default, description, choice) — set as ``name:=value``; a value outside ``choice``
  is refused;
* ``let`` (name, value);
* ``node`` (pkg, exec, name, namespace, param [name/value or from], remap [from/to], args, ros_args,
  on_exit: shutdown, output: screen) and ``executable`` (cmd, name, on_exit, output: screen);
* ``if`` / ``unless`` on any action;
* substitutions ``$(var n)``, ``$(env N [default])``, ``$(find-pkg-share p)``, ``$(dirname)``.

A node's executable is ``<prefix>/lib/<pkg>/<exec>`` on AMENT_PREFIX_PATH, as ``ros2 run`` and
``ros2 launch`` find it (tools/bootstrap.sh lays the venv out that way). Every process gets the
project ROS environment (hsa_common.rosenv) and stays in the launcher's process group, so SIGINT to
the group stops all of them. Fail fast: a process that exits non-zero while the graph runs stops the
graph; the launcher names it with its last error line and exits with its code. On SIGINT, SIGTERM,
SIGHUP (terminal closed) or SIGQUIT to the launcher, or when an ``on_exit: shutdown`` process ends,
the launcher sends SIGINT to every child, then SIGTERM after ``--sigterm-timeout`` and SIGKILL after
``--sigkill-timeout``; before the SIGKILL it prints where each child still running is stuck (its
threads as the kernel sees them, and its Python stacks: :mod:`hsa_common.stacks`). A launcher
killed outright cannot: its children get SIGTERM from the kernel then (``HSA_PARENT_PID``,
:mod:`hsa_common.parent_death`). Before starting and after stopping, the
launcher removes the Fast DDS shared-memory files that no live process uses (left by killed
processes; :mod:`hsa_common.fastdds_shm`).
"""

from __future__ import annotations

import argparse
import errno
import json
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import termios
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import yaml

from hsa_common import fastdds_shm, parent_death, rosenv, stacks
from hsa_core import cli

# innermost first: $(var a_$(var b)) nests
_SUBST = re.compile(r"\$\(([a-z-]+)((?:\s+[^)\s$]+)*)\s*\)")


_ANSI = re.compile(r"\x1b\[[0-9;]*m")

STACKS_WAIT = 1.0
"""[s] how long a stuck process has to print its stacks before SIGKILL."""
STUCK = "did not stop on SIGINT or SIGTERM"
"""The words that open the launcher's report on a process it is about to SIGKILL."""

# The keys the real parsers read (launch 3.4.3
# ExecuteProcess/DeclareLaunchArgument/SetLaunchConfiguration.parse, launch_ros 0.26.6 Node.parse;
# launch_yaml refuses any other key of an action with "Unexpected key(s) found in").
_CONDITION = {"if", "unless"}
_PROCESS = _CONDITION | {
    "cmd",
    "cwd",
    "name",
    "on_exit",
    "launch-prefix",
    "output",
    "respawn",
    "respawn_max_retries",
    "respawn_delay",
    "sigkill_timeout",
    "sigterm_timeout",
    "shell",
    "emulate_tty",
    "env",
}
SCHEMA: dict[str, set[str]] = {
    "arg": _CONDITION | {"name", "default", "description", "choice"},
    "let": _CONDITION | {"name", "value"},
    "executable": _PROCESS,
    "node": (_PROCESS - {"cmd"})
    | {"args", "ros_args", "node-name", "exec_name", "pkg", "exec", "namespace", "remap", "param"},
}
_REQUIRED = {
    "arg": {"name"},
    "let": {"name", "value"},
    "executable": {"cmd"},
    "node": {"pkg", "exec"},  # pkg: ours
}
_IMPLEMENTED = {
    "arg": SCHEMA["arg"],
    "let": SCHEMA["let"],
    "executable": _CONDITION | {"cmd", "name", "on_exit", "output"},
    "node": _CONDITION
    | {
        "pkg",
        "exec",
        "name",
        "namespace",
        "param",
        "remap",
        "args",
        "ros_args",
        "on_exit",
        "output",
    },
}
_WHY_NOT = {
    "respawn": "a process that exits stops the graph (fail fast); restart the graph instead"
}


class LaunchError(RuntimeError):
    """The launch file is malformed or names something that does not exist."""


@dataclass
class Process:
    """One process of the graph."""

    name: str
    cmd: list[str]
    shutdown_on_exit: bool = False
    popen: subprocess.Popen | None = field(default=None, repr=False)
    # last stderr lines
    errors: deque[str] = field(default_factory=lambda: deque(maxlen=50), repr=False)
    pump: threading.Thread | None = field(default=None, repr=False)

    def message(self) -> str:
        """The process's last ERROR/FATAL line (or the last line it wrote to stderr)."""
        lines = [line for line in self.errors if line.strip()]
        for line in reversed(lines):
            if "FATAL" in line or "ERROR" in line or "Error" in line:
                return line.strip()
        return lines[-1].strip() if lines else "no message"


def check_entity(kind: str, spec: object, where: str) -> None:
    """Refuse what the real launch_yaml parser refuses, and what it accepts but this launcher does
    not implement."""
    if not isinstance(spec, dict):
        raise LaunchError(f"{where}: '{kind}' must be a mapping of keys, got {spec!r}")
    unexpected = sorted(set(spec) - SCHEMA[kind])
    if unexpected:
        raise LaunchError(
            f"{where}: Unexpected key(s) found in '{kind}': {unexpected} (ros2 launch refuses them "
            f"too; allowed: {sorted(SCHEMA[kind])})"
        )
    missing = sorted(_REQUIRED[kind] - set(spec))
    if missing:
        raise LaunchError(f"{where}: '{kind}' needs {missing}")
    for key in sorted(set(spec) - _IMPLEMENTED[kind]):
        reason = _WHY_NOT.get(key, "use ros2 launch for it, or leave it out")
        raise LaunchError(
            f"{where}: key '{key}' of '{kind}' is valid for ros2 launch but not implemented by "
            f"hsa_launch: {reason}"
        )
    for key in (
        "name",
        "pkg",
        "exec",
        "namespace",
        "args",
        "ros_args",
        "cmd",
        "default",
        "description",
        "if",
        "unless",
        "on_exit",
        "output",
    ):
        if key in spec and not isinstance(spec[key], str):
            raise LaunchError(
                f"{where}: '{key}' of '{kind}' must be a string (quote it), got {spec[key]!r}"
            )
    if "on_exit" in spec and spec["on_exit"] != "shutdown":
        raise LaunchError(
            f"{where}: on_exit must be 'shutdown' (the only value launch_yaml accepts), "
            f"got {spec['on_exit']!r}"
        )
    if "output" in spec and spec["output"] != "screen":
        raise LaunchError(
            f"{where}: hsa_launch implements output 'screen' only (every process writes to the "
            f"terminal), got {spec['output']!r}"
        )
    for key, allowed in (
        ("param", ({"name", "value"}, {"from"})),
        ("remap", ({"from", "to"},)),
        ("choice", ({"value"},)),
    ):
        items = spec.get(key, [])
        if not isinstance(items, list) or not all(isinstance(i, dict) for i in items):
            raise LaunchError(f"{where}: '{key}' of '{kind}' must be a list of mappings")
        for item in items:
            if not any(set(item) == keys for keys in allowed):
                raise LaunchError(
                    f"{where}: {key} entry {item!r} must have exactly the keys "
                    f"{' or '.join(str(sorted(k)) for k in allowed)} (hsa_launch)"
                )


def package_share(pkg: str) -> Path:
    """The share directory of an installed package, from the ament index on AMENT_PREFIX_PATH."""
    for prefix in os.environ.get("AMENT_PREFIX_PATH", sys.prefix).split(os.pathsep):
        if (Path(prefix) / "share/ament_index/resource_index/packages" / pkg).exists():
            return Path(prefix) / "share" / pkg
    raise LaunchError(f"package '{pkg}' not found in the ament index (AMENT_PREFIX_PATH)")


def find_executable(pkg: str, exe: str) -> str:
    """Resolve like ``ros2 run`` and ``ros2 launch``: the first <prefix>/lib/<pkg>/<exe> on
    AMENT_PREFIX_PATH."""
    package_share(pkg)  # the package must be installed
    for prefix in os.environ.get("AMENT_PREFIX_PATH", sys.prefix).split(os.pathsep):
        candidate = Path(prefix) / "lib" / pkg / exe
        if candidate.is_file() and os.access(candidate, os.X_OK):
            return str(candidate)
    raise LaunchError(
        f"executable '{exe}' of package '{pkg}' not found in lib/{pkg}/ of any AMENT_PREFIX_PATH "
        f"prefix (run tools/bootstrap.sh, or colcon build)"
    )


class LaunchFile:
    """A parsed launch file with its arguments resolved."""

    def __init__(self, path: Path, args: dict[str, str]) -> None:
        self.path = path.resolve()
        doc = yaml.safe_load(path.read_text())
        if not isinstance(doc, dict) or not isinstance(doc.get("launch"), list):
            raise LaunchError(f"{path}: expected a top-level 'launch:' list")
        self.actions: list[dict[str, Any]] = doc["launch"]
        for index, action in enumerate(self.actions):
            if not isinstance(action, dict) or len(action) != 1:
                raise LaunchError(
                    f"{path.name}: entry {index + 1} must be a mapping with one key (the action "
                    "type)"
                )
            kind = next(iter(action))
            if kind not in SCHEMA:
                raise LaunchError(
                    f"{path.name}: entry {index + 1}: action '{kind}' is not implemented by "
                    f"hsa_launch (implemented: {sorted(SCHEMA)})"
                )
            check_entity(kind, action[kind], f"{path.name} entry {index + 1}")
        self.vars: dict[str, str] = {}
        declared = set()
        for action in self.actions:
            if "arg" in action:
                spec = action["arg"]
                declared.add(spec["name"])
                if spec["name"] in args:
                    self.vars[spec["name"]] = args[spec["name"]]
                elif "default" in spec:
                    self.vars[spec["name"]] = self.substitute(str(spec["default"]))
                else:
                    raise LaunchError(
                        f"launch argument '{spec['name']}' has no default and was not given"
                    )
                choices = [c["value"] for c in spec.get("choice", [])]
                if choices and self.vars[spec["name"]] not in choices:
                    raise LaunchError(
                        f"launch argument {spec['name']}:={self.vars[spec['name']]} is not one of "
                        f"{choices}"
                    )
            elif "let" in action and self._enabled(action["let"]):
                self.vars[action["let"]["name"]] = self.substitute(str(action["let"]["value"]))
        unknown = set(args) - declared
        if unknown:
            raise LaunchError(
                f"unknown launch argument(s) {sorted(unknown)}; declared: {sorted(declared)}"
            )

    def substitute(self, text: str) -> str:
        """Expand the supported $(...) substitutions."""

        def one(match: re.Match[str]) -> str:
            kind, rest = match.group(1), match.group(2).split()
            if kind == "var":
                if rest[0] not in self.vars:
                    raise LaunchError(f"$(var {rest[0]}) is not defined")
                return self.vars[rest[0]]
            if kind == "env":
                value = os.environ.get(rest[0], rest[1] if len(rest) > 1 else None)
                if value is None:
                    raise LaunchError(f"$(env {rest[0]}) is not set and has no default")
                return value
            if kind == "find-pkg-share":
                return str(package_share(rest[0]))
            if kind == "dirname":
                return str(self.path.parent)
            raise LaunchError(f"unsupported substitution $({kind})")

        previous = None
        while previous != text:
            previous, text = text, _SUBST.sub(one, text)
        return text

    def _enabled(self, spec: dict[str, Any]) -> bool:
        truth = {"true": True, "1": True, "false": False, "0": False}
        for key, want in (("if", True), ("unless", False)):
            if key in spec:
                value = self.substitute(str(spec[key])).lower()
                if value not in truth:
                    raise LaunchError(f"'{key}: {spec[key]}' is not a boolean")
                if truth[value] != want:
                    return False
        return True

    def processes(self) -> list[Process]:
        """The processes to start, in file order."""
        procs = []
        for action in self.actions:
            if "node" in action and self._enabled(action["node"]):
                procs.append(self._node(action["node"]))
            elif "executable" in action and self._enabled(action["executable"]):
                spec = action["executable"]
                cmd = shlex.split(self.substitute(str(spec["cmd"])))
                cmd[0] = (
                    shutil.which(
                        cmd[0],
                        path=os.pathsep.join(
                            [str(Path(sys.prefix) / "bin"), os.environ.get("PATH", "")]
                        ),
                    )
                    or cmd[0]
                )
                procs.append(
                    Process(
                        spec.get("name", Path(cmd[0]).name), cmd, spec.get("on_exit") == "shutdown"
                    )
                )
        return procs

    def _node(self, spec: dict[str, Any]) -> Process:
        sub = self.substitute
        exe = find_executable(sub(spec["pkg"]), sub(spec["exec"]))
        cmd = [exe, *shlex.split(sub(str(spec.get("args", "")))), "--ros-args"]
        name = sub(spec.get("name", spec["exec"]))
        if "name" in spec:  # as launch_ros: without one, each node keeps its own (hsa_compose)
            cmd += ["-r", f"__node:={name}"]
        if "namespace" in spec:
            cmd += [
                "-r",
                f"__ns:=/{sub(spec['namespace']).lstrip('/')}",  # launch_ros makes it absolute too
            ]
        for param in spec.get("param", []):
            if "from" in param:
                file = Path(sub(param["from"]))
                if not file.is_file():
                    raise LaunchError(f"parameter file {file} of node '{name}' does not exist")
                cmd += ["--params-file", str(file)]
            else:
                value = param["value"]
                if isinstance(
                    value, list
                ):  # substitutions inside a list's string elements, as launch_ros does
                    value = [sub(v) if isinstance(v, str) else v for v in value]
                value = sub(value) if isinstance(value, str) else json.dumps(value)
                cmd += ["-p", f"{param['name']}:={value}"]
        for remap in spec.get("remap", []):
            cmd += ["-r", f"{sub(remap['from'])}:={sub(remap['to'])}"]
        cmd += shlex.split(sub(str(spec.get("ros_args", ""))))
        return Process(name, cmd, spec.get("on_exit") == "shutdown")


class Launcher:
    """Starts the processes of a launch file and stops them all together."""

    def __init__(
        self,
        procs: list[Process],
        sigterm_timeout: float = 5.0,
        sigkill_timeout: float = 5.0,
        log: BinaryIO | None = None,
    ) -> None:
        """``log``: a binary file that gets the children's output and the launcher's lines instead
        of the terminal (errors that stop the graph are still printed)."""
        self.procs = procs
        self.log = log
        self.sigterm_timeout = sigterm_timeout
        self.sigkill_timeout = sigkill_timeout
        self._stop_requested = False
        self._interrupted: set[int] = set()  # pids of the children sent SIGINT

    def _request_stop(self, signum: int, _frame: object) -> None:
        """A stop signal: forward SIGINT to the children at once (torque-off must not wait for the
        poll loop)."""
        self._stop_requested = True
        self._interrupt([p for p in self.procs if p.popen is not None and p.popen.poll() is None])
        if signum == signal.SIGHUP:
            _leave_dead_terminal()

    def _interrupt(self, procs: list[Process]) -> None:
        """SIGINT each process once: a second one could land in its interpreter teardown, where it
        kills."""
        for p in procs:
            if p.popen.pid not in self._interrupted:
                self._interrupted.add(p.popen.pid)
                p.popen.send_signal(signal.SIGINT)

    def run(self) -> int:
        """Start everything, wait for a stop condition, stop everything; return the failed or worst
        exit code."""
        # inherits this process's reserved domain (rosenv.apply in main)
        env = rosenv.ros_environment()
        # the children's check that this launcher still lives
        env[parent_death.PARENT_ENV] = str(os.getpid())
        parent_death.on_stop_signals(self._request_stop)
        self._remove_unused_shm()
        for proc in self.procs:
            self._say(f"[launch] starting {proc.name}: {shlex.join(proc.cmd)}")
            proc.popen = subprocess.Popen(
                proc.cmd, env=env, stderr=subprocess.PIPE, stdout=self.log
            )
            proc.pump = threading.Thread(target=_pump, args=(proc, self.log), daemon=True)
            proc.pump.start()
        failed: Process | None = None
        while not self._stop_requested:
            ended = [p for p in self.procs if p.popen.poll() is not None]
            failed = next((p for p in ended if _failure(p.popen.returncode)), None)
            if failed or any(p.shutdown_on_exit for p in ended) or len(ended) == len(self.procs):
                break
            time.sleep(0.05)
        if failed is not None:
            failed.pump.join(timeout=2.0)  # its last lines, before they are named
            _print(
                f"[launch] error: {failed.name} exited with {failed.popen.returncode}: "
                f"{failed.message()}; stopping the graph",
                "stderr",
            )
        worst = self.stop()
        self._remove_unused_shm()
        return _exit_status(failed.popen.returncode) if failed is not None else worst

    def _say(self, line: str) -> None:
        """A launcher line, to the log if there is one, else to stdout."""
        if self.log is not None:
            self.log.write(line.encode() + b"\n")
            self.log.flush()
        else:
            _print(line, "stdout")

    def _remove_unused_shm(self) -> None:
        """Remove the Fast DDS shared-memory files no live process uses (best effort: it never stops
        a launch)."""
        try:
            removed = fastdds_shm.remove_unused()
        except OSError as exc:
            self._say(f"[launch] could not check /dev/shm for unused Fast DDS files: {exc}")
            return
        if removed:
            self._say(
                f"[launch] removed {len(removed)} Fast DDS shared-memory files that no live "
                "process uses"
            )

    def _report_stuck(self, procs: list[Process]) -> None:
        """Say where each process that ignored SIGINT and SIGTERM is stuck: its threads as the
        kernel sees them, then its Python stacks (:mod:`hsa_common.stacks`; a process not started
        by the runner ends on that signal instead)."""
        for p in procs:
            self._say(
                f"[launch] {p.name} (PID {p.popen.pid}) {STUCK}; its threads, then (a node under "
                "hsa_common.runner) its Python stacks:"
            )
            for line in stacks.kernel_view(p.popen.pid):
                self._say(f"[launch]   {line}")
            p.popen.send_signal(stacks.SIGNAL)
        time.sleep(STACKS_WAIT)

    def stop(self) -> int:
        """SIGINT all children, escalate after timeouts, and report how each ended."""
        for sig, timeout in (
            (signal.SIGINT, self.sigterm_timeout),
            (signal.SIGTERM, self.sigkill_timeout),
            (signal.SIGKILL, 5.0),
        ):
            alive = [p for p in self.procs if p.popen.poll() is None]
            if not alive:
                break
            if sig == signal.SIGINT:
                self._interrupt(alive)
            else:
                if sig == signal.SIGKILL:
                    self._report_stuck(alive)
                for p in alive:
                    p.popen.send_signal(sig)
            deadline = time.monotonic() + timeout
            while time.monotonic() < deadline and any(p.popen.poll() is None for p in alive):
                time.sleep(0.02)
        worst = 0
        for p in self.procs:
            code = p.popen.wait()
            p.pump.join(timeout=2.0)
            self._say(f"[launch] {p.name} exited with {code}")
            if _failure(code):
                worst = worst or _exit_status(code)
        return worst


def _leave_dead_terminal() -> None:
    """Point stdout and stderr at /dev/null where they are a terminal that was hung up (EIO): the
    rest of the process (the launcher's report, run_sim_experiment.py's analysis) then runs to its
    end instead of failing on a write."""
    for fd in (1, 2):
        try:
            termios.tcgetattr(fd)
        except termios.error as exc:
            if exc.args[0] == errno.EIO:  # a pipe or a file answers ENOTTY
                null = os.open(os.devnull, os.O_WRONLY)
                os.dup2(null, fd)
                os.close(null)


def _print(line: str, stream: str) -> None:
    """Print a line to sys.``stream``; once the terminal is closed (EIO) the stream goes to
    /dev/null instead: a hung-up terminal must neither stop the launcher half-way through stopping
    the graph nor fail its exit."""
    try:
        print(line, file=getattr(sys, stream), flush=True)
    except OSError:
        setattr(sys, stream, open(os.devnull, "w"))  # noqa: SIM115 - for the rest of the process


def _failure(code: int | None) -> bool:
    """An exit that means the process failed (not 0, not the SIGINT the launcher or the terminal
    sent)."""
    return code is not None and code not in (0, -signal.SIGINT)


def _exit_status(code: int) -> int:
    """A child's return code as a shell exit status (128 + N for a death by signal N)."""
    return code if code > 0 else 128 - code


def _pump(proc: Process, log: BinaryIO | None = None) -> None:
    """Copy the process's stderr to ours (or to ``log``) line by line, keeping the last lines for
    the failure message.

    It drains the pipe to the end even if our stderr is gone: a full pipe would block the child's
    logging.
    """
    assert proc.popen is not None and proc.popen.stderr is not None
    out = log if log is not None else sys.stderr.buffer
    for raw in iter(proc.popen.stderr.readline, b""):
        try:
            out.write(raw)
            out.flush()
        except (OSError, ValueError):
            pass  # our stderr was closed: keep draining
        proc.errors.append(_ANSI.sub("", raw.decode(errors="replace")))
    proc.popen.stderr.close()


def parse_args(argv: list[str]) -> tuple[argparse.Namespace, dict[str, str]]:
    """Split the command line into options and ``name:=value`` launch arguments."""
    parser = cli.ArgumentParser(prog="hsa_launch", description=__doc__.splitlines()[0])
    parser.add_argument("launch_file", type=Path)
    parser.add_argument("--sigterm-timeout", type=cli.positive, default=5.0, metavar="S")
    parser.add_argument("--sigkill-timeout", type=cli.positive, default=5.0, metavar="S")
    parser.add_argument("--print", action="store_true", help="print the commands and exit")
    opts, rest = parser.parse_known_args(argv)
    launch_args = {}
    for item in rest:
        if ":=" not in item:
            parser.error(f"launch arguments are name:=value, got {item!r}")
        key, value = item.split(":=", 1)
        launch_args[key] = value
    return opts, launch_args


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point (``hsa_launch file.launch.yaml name:=value ...``)."""
    opts, launch_args = parse_args(sys.argv[1:] if argv is None else argv)
    # before substitutions: $(env ROS_DOMAIN_ID) must name the domain the nodes will use
    rosenv.apply()
    try:
        procs = LaunchFile(opts.launch_file, launch_args).processes()
    except (LaunchError, OSError, KeyError, yaml.YAMLError) as exc:
        print(f"[launch] error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    if opts.print:
        for proc in procs:
            print(shlex.join(proc.cmd))
        return 0
    return Launcher(procs, opts.sigterm_timeout, opts.sigkill_timeout).run()


if __name__ == "__main__":
    sys.exit(main())
