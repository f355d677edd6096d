#!/usr/bin/env bash
# The main job: bootstraps the environment if needed, then runs the FPU step experiment (11 setpoints, 110 s) in
# simulation through the full ROS graph, records a bag, prints the metrics table and writes the figures.
# Arguments go to launch_scripts/run_sim_experiment.py (e.g. --controller pid, --material epu, --out DIR).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
bash "$ROOT/tools/bootstrap.sh"
cd "$ROOT"
exec "$ROOT/.venv/bin/python" "$ROOT/launch_scripts/run_sim_experiment.py" "$@"
