"""The main job: the paper's step experiment through the full ROS graph with the simulator in place
of the robot.

Starts launch_scripts/sim.launch.yaml (simulator, real Dynamixel driver on the emulated bus, mocap
bridge, kinematics, planner, controller, setpoint sequencer, MCAP recorder), waits until the
sequencer has played the whole trajectory, stops the graph, then reads the recorded bag and prints
the metrics table and writes the figures. By default the graph runs in lockstep simulated time
(deterministic, faster than real time); ``--clock wall`` runs it in real time. One progress line per
step; the nodes' output goes to ``<out>/graph.log`` unless ``--verbose``.

    python launch_scripts/run_sim_experiment.py [--material fpu] [--controller psatid] [--out
    out/run_<time>]

A run's conditions: ``--profile sep2023`` (a run profile: control rate, integrators' step, velocity
estimator, σ_a,eq, payload), ``--run 20230925_093236`` (a real run of the paper replayed with its
own conditions, gains and setpoints at its real step instants), ``--payload KG`` and ``--sigma-a-eq
A[,B]`` (overrides); hsa_core.sim.run_conditions turns them into the graph's launch arguments, as
hsa_experiment does for the offline run.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from pathlib import Path

import numpy as np
import yaml

from hsa_bag.analysis import analyze
from hsa_common import convert, rosenv
from hsa_common.launcher import Launcher, LaunchFile
from hsa_core import cli
from hsa_core.analysis import metrics
from hsa_core.apps.tune import gains_yaml
from hsa_core.jaxsetup import configure_jax
from hsa_core.runs.profiles import DEFAULT_PROFILE, load_profile
from hsa_core.sim.disturbance import DEFAULT_WORLD, WORLDS
from hsa_core.sim.experiment import replay_config
from hsa_core.sim.run_conditions import graph_arguments, run_schedule

GRAPH = Path(__file__).with_name("sim.launch.yaml")


class StepMonitor:
    """Prints one line per finished step from /hsa/controller_info (its own rclpy context, outside
    the barrier)."""

    def __init__(self) -> None:
        import rclpy
        from rclpy.node import Node
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

        from hsa_msgs.msg import ControllerInfo

        self._rclpy = rclpy
        self._context = rclpy.Context()
        rclpy.init(context=self._context)
        self._node = Node("run_monitor", context=self._context, enable_rosout=False)
        qos = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
        self._tracking = ControllerInfo.STATE_TRACKING
        self._node.create_subscription(ControllerInfo, "/hsa/controller_info", self._on_info, qos)
        self._rows: list[tuple[float, float, float, float, float]] = []  # t, x_des, y_des, x, y
        self._index, self._length = -1, 0
        self._wall0 = time.monotonic()
        self._t0: float | None = None
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

        executor = SingleThreadedExecutor(context=self._context)
        executor.add_node(self._node)
        try:
            while self._context.ok():
                executor.spin_once(timeout_sec=0.1)
        except ExternalShutdownException:
            pass  # close() shut the context down

    def _on_info(self, msg) -> None:
        if msg.state != self._tracking:
            return
        t = convert.stamp_s(msg.header.stamp)
        self._t0 = t if self._t0 is None else self._t0
        if msg.setpoint.trajectory_index != self._index:
            self._report()
            self._index, self._length = (
                msg.setpoint.trajectory_index,
                msg.setpoint.trajectory_length,
            )
        self._rows.append((t, msg.chiee_des.x, msg.chiee_des.y, msg.chiee.x, msg.chiee.y))

    def _report(self) -> None:
        """One line for the step whose ticks are collected (if it has enough to evaluate)."""
        if len(self._rows) < 3:
            self._rows.clear()
            return
        rows = np.array(self._rows)
        self._rows.clear()
        t = rows[:, 0] - rows[0, 0]
        step = metrics.evaluate_run(
            t, rows[:, 1:3], rows[:, 3:5], duration=t[-1] + (t[1] - t[0])
        ).steps[0]
        error = np.linalg.norm(rows[-1, 1:3] - rows[-1, 3:5])
        sim = rows[-1, 0] - (self._t0 or rows[0, 0])
        print(
            f"[run] step {self._index + 1}/{self._length}: target ({rows[0, 1] * 1e3:6.1f}, "
            f"{rows[0, 2] * 1e3:6.1f}) mm, final error {error * 1e3:5.2f} mm, t_r "
            f"{step.response_time:5.2f} s; simulated {sim:6.1f} s, wall "
            f"{time.monotonic() - self._wall0:6.1f} s",
            flush=True,
        )

    def close(self) -> None:
        """Report the last step and stop."""
        self._report()
        self._context.try_shutdown()
        self._thread.join(timeout=2.0)


def _gains_file(text: str) -> Path:
    """argparse type of --gains: an existing ROS parameter file (absolute path: the nodes run
    elsewhere)."""
    path = Path(text)
    if not path.is_file():
        raise argparse.ArgumentTypeError(f"no such file: {text}")
    try:
        doc = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise argparse.ArgumentTypeError(
            f"{text} is not YAML: {str(exc).splitlines()[0]}"
        ) from None
    if not isinstance(doc, dict) or not any(
        isinstance(v, dict) and "ros__parameters" in v for v in doc.values()
    ):
        raise argparse.ArgumentTypeError(
            f"{text} is not a ROS parameter file (no '<node>: ros__parameters:')"
        )
    return path.resolve()


def _conditions(args: argparse.Namespace) -> dict[str, str]:
    """Launch arguments of the run's conditions (hsa_core.sim.run_conditions); a real run's gains
    and setpoints are written as parameter files under --out."""
    if args.run is None:
        return graph_arguments(
            args.profile or load_profile(DEFAULT_PROFILE),
            sigma_a_eq=args.sigma_a_eq,
            payload=args.payload,
        )
    cond = args.run.conditions
    gains = args.out / "gains.yaml"
    gains.write_text(gains_yaml(cond.law, cond.gains, f"gains of the real run {cond.bag}"))
    sequencer = args.out / "sequencer.yaml"
    schedule = run_schedule(args.run) | {"exit_on_finish": True, "finish_hold": 2.0}
    # a launch argument: the graph gives it to the sequencer after its file
    rate = schedule.pop("rate")
    sequencer.write_text(yaml.safe_dump({"/**": {"ros__parameters": schedule}}))
    replay = replay_config(args.run, sigma_a_eq=args.sigma_a_eq, payload=args.payload)
    return graph_arguments(
        cond.profile,
        sigma_a_eq=replay.sigma_a_eq,
        plant_sigma_a_eq=replay.plant_sigma_a_eq,
        payload=replay.payload,
        run=args.run,
    ) | {
        "gains": str(gains.resolve()),
        "sequencer_config": str(sequencer.resolve()),
        "setpoint_rate": repr(rate),
    }


def main(argv: list[str] | None = None) -> int:
    """Run the graph, then analyse its bag; exit code 0 only if both succeeded."""
    for sig in (
        signal.SIGHUP,
        signal.SIGQUIT,
    ):  # a closed terminal ends the run like Ctrl-C (unless nohup); the
        if (
            signal.getsignal(sig) != signal.SIG_IGN
        ):  # launcher's own handlers take over while the graph runs
            signal.signal(sig, signal.default_int_handler)
    configure_jax()
    parser = cli.ArgumentParser(prog="run_sim_experiment.py", description=__doc__.splitlines()[0])
    parser.add_argument("--material", choices=["fpu", "epu"], default="fpu")
    parser.add_argument("--controller", choices=["psatid", "psatid_gc", "pid"], default="psatid")
    parser.add_argument(
        "--ee-integral", action="store_true", help="add the EE-position integral extension"
    )
    parser.add_argument(
        "--disturbance",
        type=cli.world_name,
        choices=WORLDS,
        default=DEFAULT_WORLD,
        help="the world (hsa_core.sim.disturbance.named_world); calibrated (the default): fitted "
        "to the robot; declared: the hand-declared model",
    )
    parser.add_argument(
        "--setpoint-rate",
        type=cli.non_negative,
        default=0.0,
        help="[Hz] setpoints per second; 0 = the paper's (one step every 10 s, 110 s in all)",
    )
    parser.add_argument(
        "--clock",
        choices=["lockstep", "wall"],
        default="lockstep",
        help="lockstep: simulated time, deterministic and faster than real time (default); "
        "wall: real time",
    )
    parser.add_argument(
        "--rate",
        type=cli.positive,
        default=None,
        help="[Hz] control rate (default: the run's or the profile's, 40 Hz for lab)",
    )
    cli.add_run_conditions(parser)
    parser.add_argument(
        "--gains",
        type=_gains_file,
        default=None,
        help="controller parameter file given after the material's (e.g. hsa_tune's gains.yaml)",
    )
    parser.add_argument(
        "--verbose", action="store_true", help="show the nodes' output instead of logging it"
    )
    parser.add_argument(
        "--live",
        action="store_true",
        help="serve the run to Foxglove on ws://127.0.0.1:8765 (hsa_live; docs/nodes/hsa_live.md)",
    )
    parser.add_argument(
        "--out", type=Path, default=Path("out") / time.strftime("run_%Y%m%d-%H%M%S")
    )
    args = parser.parse_args(argv)
    cli.run_with_images(parser, args)
    if args.run is not None and args.profile is not None:
        parser.error("--run replays a run with its own profile; --profile does not apply")

    bag = args.out / "bag"
    if bag.exists():
        parser.error(f"{bag} exists; choose another --out")
    # the user's ROS_DOMAIN_ID, or a reserved one; a bad one is refused before --out is made
    domain = rosenv.apply()
    args.out.mkdir(parents=True, exist_ok=True)
    launch_args = {
        "material": args.material,
        "controller": args.controller,
        "ee_integral": str(args.ee_integral).lower(),
        "disturbance": args.disturbance,
        "setpoint_rate": str(args.setpoint_rate),
        "bag_dir": str(bag),
        "clock": args.clock,
        "live": str(args.live).lower(),
    } | _conditions(args)
    if args.rate is not None:
        launch_args["rate"] = str(args.rate)
    if args.gains is not None:
        launch_args["gains"] = str(args.gains)
    log_path = args.out / "graph.log"
    print(f"[run] ROS_DOMAIN_ID={domain}; graph {GRAPH.name} with {launch_args}", flush=True)
    if not args.verbose:
        print(f"[run] node output: {log_path.resolve()} (--verbose shows it here)", flush=True)
    if args.live:
        print(
            "[run] live view: open ws://127.0.0.1:8765 in Foxglove (layout: "
            "share/hsa_live/config/)",
            flush=True,
        )
    started = time.monotonic()
    monitor = StepMonitor()
    with open(log_path, "wb") as log:
        code = Launcher(
            LaunchFile(GRAPH, launch_args).processes(), log=None if args.verbose else log
        ).run()
    monitor.close()
    print(
        f"[run] graph finished after {time.monotonic() - started:.1f} s of wall time (exit {code})",
        flush=True,
    )
    eei = "_eei" if args.ee_integral else ""
    name = f"{launch_args['material']}_{launch_args['controller']}{eei}_ros"
    if args.run is not None:  # the run's own length, as the offline experiment's metrics
        duration: float | None = args.run.timed_reference().duration
    else:
        duration = None if args.setpoint_rate else 110.0
    result = analyze(bag, args.out, duration=duration, csv=True, npz=True, name=name)
    print(result.report)
    print(f"[run] bag: {bag.resolve()}")
    print(f"[run] metrics.txt, run.csv, run.npz and figures/: {args.out.resolve()}")
    return code


if __name__ == "__main__":
    sys.exit(main())
