#!/usr/bin/env bash
# The test command: bootstraps the environment on a fresh machine (skipped when nothing changed), then runs every test.
# Extra arguments go to pytest, e.g. ./test.sh tests/core -k kinematics
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
bash "$ROOT/tools/bootstrap.sh"
cd "$ROOT"
exec "$ROOT/.venv/bin/python" -m pytest "${@:-tests}"
