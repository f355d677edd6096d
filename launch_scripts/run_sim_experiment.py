"""The main job: the paper's step experiment through the full ROS graph with the simulator in place of the robot.

Starts launch_scripts/sim.launch.yaml (simulator, real Dynamixel driver on the emulated bus, mocap bridge, kinematics,
planner, controller, setpoint sequencer, MCAP recorder), waits until the sequencer has played the whole trajectory,
stops the graph, then reads the recorded bag and prints the metrics table and writes the figures.

    python launch_scripts/run_sim_experiment.py [--material fpu] [--controller psatid] [--out out/run_<time>]
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from hsa_bag.analysis import analyze
from hsa_common.launcher import Launcher, LaunchFile
from hsa_core import cli, rosenv

GRAPH = Path(__file__).with_name("sim.launch.yaml")


def main(argv: list[str] | None = None) -> int:
    """Run the graph, then analyse its bag; exit code 0 only if both succeeded."""
    parser = cli.ArgumentParser(prog="run_sim_experiment.py", description=__doc__.splitlines()[0])
    parser.add_argument("--material", choices=["fpu", "epu"], default="fpu")
    parser.add_argument("--controller", choices=["psatid", "psatid_gc", "pid"], default="psatid")
    parser.add_argument("--ee-integral", action="store_true", help="add the EE-position integral extension")
    parser.add_argument("--disturbance", choices=["none", "default"], default="default")
    parser.add_argument("--setpoint-rate", type=cli.non_negative, default=0.0,
                        help="[Hz] setpoints per second; 0 = the paper's (one step every 10 s, 110 s in all)")
    parser.add_argument("--out", type=Path, default=Path("out") / time.strftime("run_%Y%m%d-%H%M%S"))
    args = parser.parse_args(argv)

    bag = args.out / "bag"
    if bag.exists():
        parser.error(f"{bag} exists; choose another --out")
    args.out.mkdir(parents=True, exist_ok=True)
    domain = rosenv.apply()
    launch_args = {
        "material": args.material, "controller": args.controller, "ee_integral": str(args.ee_integral).lower(),
        "disturbance": args.disturbance, "setpoint_rate": str(args.setpoint_rate), "bag_dir": str(bag),
    }
    print(f"[run] ROS_DOMAIN_ID={domain}; graph {GRAPH.name} with {launch_args}", flush=True)
    started = time.monotonic()
    code = Launcher(LaunchFile(GRAPH, launch_args).processes()).run()
    print(f"[run] graph finished after {time.monotonic() - started:.0f} s (exit {code})", flush=True)
    result = analyze(bag, args.out / "figures", duration=None if args.setpoint_rate else 110.0, csv=True, npz=True,
                     name=f"{args.material}_{args.controller}{'_eei' if args.ee_integral else ''}_ros")
    print(result.report)
    print(f"[run] bag: {bag.resolve()}")
    print(f"[run] figures, metrics.txt, run.csv, run.npz: {(args.out / 'figures').resolve()}")
    return code


if __name__ == "__main__":
    sys.exit(main())
