"""Run a ROS 2 YAML launch file (launch_scripts/*.launch.yaml) without ros2launch, which is not installable here.

The same file works with ``ros2 launch <file>`` on a full ROS install; this launcher implements the subset our
graphs use, with the same meaning:

* ``arg`` (name, default, description) — set as ``name:=value`` on the command line;
* ``let`` (name, value);
* ``node`` (pkg, exec, name, namespace, param [name/value or from], remap [from/to], args, ros_args, on_exit:
  shutdown, output) and ``executable`` (cmd, name, on_exit);
* ``if`` / ``unless`` on any action;
* substitutions ``$(var n)``, ``$(env N [default])``, ``$(find-pkg-share p)``, ``$(dirname)``.

Every process gets the project ROS environment (hsa_core.rosenv) and stays in the launcher's process group, so
SIGINT to the group stops all of them. On SIGINT/SIGTERM to the launcher, or when an ``on_exit: shutdown``
process ends, the launcher sends SIGINT to every child, then SIGTERM after ``--sigterm-timeout`` and SIGKILL after
``--sigkill-timeout``; nothing is orphaned.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from hsa_core import rosenv

_SUBST = re.compile(r"\$\(([a-z-]+)((?:\s+[^)\s]+)*)\s*\)")


class LaunchError(RuntimeError):
    """The launch file is malformed or names something that does not exist."""


@dataclass
class Process:
    """One process of the graph."""

    name: str
    cmd: list[str]
    shutdown_on_exit: bool = False
    popen: subprocess.Popen | None = field(default=None, repr=False)


def package_share(pkg: str) -> Path:
    """The share directory of an installed package, from the ament index on AMENT_PREFIX_PATH."""
    for prefix in os.environ.get("AMENT_PREFIX_PATH", sys.prefix).split(os.pathsep):
        if (Path(prefix) / "share/ament_index/resource_index/packages" / pkg).exists():
            return Path(prefix) / "share" / pkg
    raise LaunchError(f"package '{pkg}' not found in the ament index (AMENT_PREFIX_PATH)")


def find_executable(pkg: str, exe: str) -> str:
    """Resolve like ``ros2 run``: <prefix>/lib/<pkg>/<exe>, else the venv's console script."""
    for prefix in os.environ.get("AMENT_PREFIX_PATH", sys.prefix).split(os.pathsep):
        candidate = Path(prefix) / "lib" / pkg / exe
        if candidate.is_file() and os.access(candidate, os.X_OK):
            return str(candidate)
    candidate = Path(sys.prefix) / "bin" / exe
    if candidate.is_file():
        package_share(pkg)  # the package must exist too
        return str(candidate)
    raise LaunchError(f"executable '{exe}' of package '{pkg}' not found")


class LaunchFile:
    """A parsed launch file with its arguments resolved."""

    def __init__(self, path: Path, args: dict[str, str]) -> None:
        self.path = path.resolve()
        doc = yaml.safe_load(path.read_text())
        if not isinstance(doc, dict) or not isinstance(doc.get("launch"), list):
            raise LaunchError(f"{path}: expected a top-level 'launch:' list")
        self.actions: list[dict[str, Any]] = doc["launch"]
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
                    raise LaunchError(f"launch argument '{spec['name']}' has no default and was not given")
            elif "let" in action:
                self.vars[action["let"]["name"]] = self.substitute(str(action["let"]["value"]))
        unknown = set(args) - declared
        if unknown:
            raise LaunchError(f"unknown launch argument(s) {sorted(unknown)}; declared: {sorted(declared)}")

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
                cmd[0] = shutil.which(cmd[0], path=os.pathsep.join([str(Path(sys.prefix) / "bin"),
                                                                      os.environ.get("PATH", "")])) or cmd[0]
                procs.append(Process(spec.get("name", Path(cmd[0]).name), cmd, spec.get("on_exit") == "shutdown"))
        return procs

    def _node(self, spec: dict[str, Any]) -> Process:
        sub = self.substitute
        exe = find_executable(sub(spec["pkg"]), sub(spec["exec"]))
        cmd = [exe, *shlex.split(sub(str(spec.get("args", "")))), "--ros-args"]
        name = sub(spec.get("name", spec["exec"]))
        cmd += ["-r", f"__node:={name}"]
        if "namespace" in spec:
            cmd += ["-r", f"__ns:=/{sub(spec['namespace']).lstrip('/')}"]  # launch_ros makes it absolute too
        for param in spec.get("param", []):
            if "from" in param:
                file = Path(sub(param["from"]))
                if not file.is_file():
                    raise LaunchError(f"parameter file {file} of node '{name}' does not exist")
                cmd += ["--params-file", str(file)]
            else:
                value = param["value"]
                value = sub(value) if isinstance(value, str) else json.dumps(value)
                cmd += ["-p", f"{param['name']}:={value}"]
        for remap in spec.get("remap", []):
            cmd += ["-r", f"{sub(remap['from'])}:={sub(remap['to'])}"]
        cmd += shlex.split(sub(str(spec.get("ros_args", ""))))
        return Process(name, cmd, spec.get("on_exit") == "shutdown")


class Launcher:
    """Starts the processes of a launch file and stops them all together."""

    def __init__(self, procs: list[Process], sigterm_timeout: float = 5.0, sigkill_timeout: float = 5.0) -> None:
        self.procs = procs
        self.sigterm_timeout = sigterm_timeout
        self.sigkill_timeout = sigkill_timeout
        self._stop_requested = False
        self._interrupted: set[int] = set()  # pids of the children sent SIGINT

    def _request_stop(self, signum: int, _frame: object) -> None:
        """SIGINT/SIGTERM: forward SIGINT to the children at once (torque-off must not wait for the poll loop)."""
        self._stop_requested = True
        self._interrupt([p for p in self.procs if p.popen is not None and p.popen.poll() is None])

    def _interrupt(self, procs: list[Process]) -> None:
        """SIGINT each process once: a second one could land in its interpreter teardown, where it kills."""
        for p in procs:
            if p.popen.pid not in self._interrupted:
                self._interrupted.add(p.popen.pid)
                p.popen.send_signal(signal.SIGINT)

    def run(self) -> int:
        """Start everything, wait for a stop condition, stop everything; return the worst child exit code."""
        env = rosenv.ros_environment()  # inherits this process's reserved domain (rosenv.apply in main)
        signal.signal(signal.SIGINT, self._request_stop)
        signal.signal(signal.SIGTERM, self._request_stop)
        for proc in self.procs:
            print(f"[launch] starting {proc.name}: {shlex.join(proc.cmd)}", flush=True)
            proc.popen = subprocess.Popen(proc.cmd, env=env)
        while not self._stop_requested:
            ended = [p for p in self.procs if p.popen.poll() is not None]
            if any(p.shutdown_on_exit for p in ended) or len(ended) == len(self.procs):
                break
            time.sleep(0.05)
        return self.stop()

    def stop(self) -> int:
        """SIGINT all children, escalate after timeouts, and report how each ended."""
        for sig, timeout in ((signal.SIGINT, self.sigterm_timeout), (signal.SIGTERM, self.sigkill_timeout),
                             (signal.SIGKILL, 5.0)):
            alive = [p for p in self.procs if p.popen.poll() is None]
            if not alive:
                break
            if sig == signal.SIGINT:
                self._interrupt(alive)
            else:
                for p in alive:
                    p.popen.send_signal(sig)
            deadline = time.monotonic() + timeout
            while time.monotonic() < deadline and any(p.popen.poll() is None for p in alive):
                time.sleep(0.02)
        worst = 0
        for p in self.procs:
            code = p.popen.wait()
            print(f"[launch] {p.name} exited with {code}", flush=True)
            if code not in (0, -signal.SIGINT) and not (p.shutdown_on_exit and code == 0):
                worst = worst or (code if code > 0 else 128 - code)
        return worst


def parse_args(argv: list[str]) -> tuple[argparse.Namespace, dict[str, str]]:
    """Split the command line into options and ``name:=value`` launch arguments."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("launch_file", type=Path)
    parser.add_argument("--sigterm-timeout", type=float, default=5.0)
    parser.add_argument("--sigkill-timeout", type=float, default=5.0)
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
    rosenv.apply()  # before substitutions: $(env ROS_DOMAIN_ID) must name the domain the nodes will use
    try:
        procs = LaunchFile(opts.launch_file, launch_args).processes()
    except (LaunchError, OSError, KeyError, yaml.YAMLError) as exc:
        print(f"[launch] error: {exc}", file=sys.stderr)
        return 2
    if opts.print:
        for proc in procs:
            print(shlex.join(proc.cmd))
        return 0
    return Launcher(procs, opts.sigterm_timeout, opts.sigkill_timeout).run()


if __name__ == "__main__":
    sys.exit(main())
