#!/usr/bin/env bash
# Installs the pinned viewer packages of package-lock.json into tools/viewer_check/node_modules (npm ci, no install
# scripts); skipped when node_modules already holds this lockfile's packages.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")"
stamp=node_modules/.hsa-lock.sha256
want="$(sha256sum package-lock.json | cut -d' ' -f1)"
if [[ -f $stamp && "$(cat "$stamp")" == "$want" ]]; then
  exit 0
fi
npm ci --ignore-scripts --no-audit --no-fund --loglevel=error
echo "$want" > "$stamp"
