#!/usr/bin/env bash
# Create or update the project venv (.venv): pinned ROS 2 Jazzy wheels + numerics, hsa_msgs built with rosidl, and
# all hsa-ros packages installed. Each stage is skipped when its inputs are unchanged (stamps in .venv/.hsa_stamps).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"  # the digests' globs (hsa_msgs/msg/*.msg, ...) name files of the checkout, whatever the caller's directory
V="$ROOT/.venv"
PY="${HSA_PYTHON:-python3}"
STAMPS="$V/.hsa_stamps"
PACKAGES=(hsa_core hsa_common hsa_mocap_bridge hsa_kinematics_node hsa_planner_node hsa_controller_node hsa_dynamixel_driver
          hsa_sim_node hsa_bag hsa_identification hsa_live)

# one bootstrap at a time per checkout (parallel test runs would otherwise install into the venv together)
mkdir -p "$ROOT/build"
exec 9> "$ROOT/build/.bootstrap.lock"
flock 9

log() { printf '[bootstrap] %s\n' "$*" >&2; }
digest() { cat "$@" | sha256sum | cut -d' ' -f1; }  # a missing input is an error with its name, not an empty hash
fresh() { [ -f "$STAMPS/$1" ] && [ "$(cat "$STAMPS/$1")" = "$2" ]; }
mark() { mkdir -p "$STAMPS" && printf '%s' "$2" > "$STAMPS/$1"; }

# 1. venv + pinned dependencies
req_hash=$(digest requirements.txt tools/bootstrap.sh)
if ! fresh deps "$req_hash" || [ ! -x "$V/bin/python" ]; then
  log "creating venv and installing pinned dependencies (about 1 minute on a fresh machine)"
  [ -x "$V/bin/python" ] || "$PY" -m venv "$V"
  "$V/bin/python" -m pip install --quiet --disable-pip-version-check "uv==0.13.9"
  "$V/bin/uv" pip install --quiet --python "$V/bin/python" -r "$ROOT/requirements.txt"
  # CMake export-path fix: the wheels hard-code their manylinux build container's Python/numpy include paths.
  PYINC=$("$V/bin/python" -c "import sysconfig; print(sysconfig.get_paths()['include'])")
  NPINC=$("$V/bin/python" -c "import numpy; print(numpy.get_include())")
  { grep -rlE --include='*.cmake' '/opt/python/cp[0-9]+-cp[0-9]+' "$V/share" || true; } | xargs -r sed -i -E \
    -e "s#/opt/python/cp[0-9]+-cp[0-9]+/lib/python3\.[0-9]+/site-packages/numpy/_core/include#$NPINC#g" \
    -e "s#/opt/python/cp[0-9]+-cp[0-9]+/include/python3\.[0-9]+#$PYINC#g"
  rm -f "$STAMPS/msgs" "$STAMPS/pkgs"
  mark deps "$req_hash"
fi

# 2. hsa_msgs (rosidl interface package) built with plain cmake into the venv prefix
msg_hash=$(digest hsa_msgs/CMakeLists.txt hsa_msgs/package.xml hsa_msgs/msg/*.msg hsa_msgs/srv/*.srv)
if ! fresh msgs "$msg_hash"; then
  log "building hsa_msgs (about 15 s)"
  rm -rf "$ROOT/build/hsa_msgs" && mkdir -p "$ROOT/build"
  export AMENT_PREFIX_PATH="$V"
  cmake -S "$ROOT/hsa_msgs" -B "$ROOT/build/hsa_msgs" -DCMAKE_INSTALL_PREFIX="$V" -DCMAKE_PREFIX_PATH="$V" \
    -DPython3_EXECUTABLE="$V/bin/python" -DCMAKE_BUILD_TYPE=Release -DBUILD_TESTING=OFF > "$ROOT/build/hsa_msgs.log" 2>&1 \
    || { cat "$ROOT/build/hsa_msgs.log"; exit 1; }
  cmake --build "$ROOT/build/hsa_msgs" -j"$(nproc)" >> "$ROOT/build/hsa_msgs.log" 2>&1 \
    || { tail -50 "$ROOT/build/hsa_msgs.log"; exit 1; }
  cmake --install "$ROOT/build/hsa_msgs" >> "$ROOT/build/hsa_msgs.log" 2>&1
  mark msgs "$msg_hash"
fi

# 3. our Python packages: editable installs (code edits need no reinstall) plus the ament index entries, package.xml,
#    config/ and launch/ linked into venv/share, and every console script linked as lib/<pkg>/<exe> (where
#    `ros2 run`, `ros2 launch` and hsa_launch look for it; setup.cfg's script_dir/install_scripts put it there under
#    colcon, but an editable wheel puts it in bin/ only) — the venv is laid out as `colcon build --symlink-install`
#    lays out install/. The bin/ entry points stay for the README commands.
pkg_hash=$(digest $(for p in "${PACKAGES[@]}"; do echo "$p/setup.py" "$p/setup.cfg" "$p/package.xml"; done))
if ! fresh pkgs "$pkg_hash"; then
  log "installing hsa-ros packages"
  args=()
  for p in "${PACKAGES[@]}"; do args+=(-e "$ROOT/$p"); done
  # --no-build-isolation: the venv's setuptools (the one colcon builds these packages with) instead of a fresh
  # build environment per package
  "$V/bin/uv" pip install --quiet --python "$V/bin/python" --no-deps --no-build-isolation \
    --config-settings editable_mode=compat "${args[@]}"
  for p in "${PACKAGES[@]}"; do
    mkdir -p "$V/share/ament_index/resource_index/packages" "$V/share/$p"
    touch "$V/share/ament_index/resource_index/packages/$p"
    ln -sfn "$ROOT/$p/package.xml" "$V/share/$p/package.xml"
    for d in config launch; do
      if [ -d "$ROOT/$p/$d" ]; then ln -sfn "$ROOT/$p/$d" "$V/share/$p/$d"; fi
    done
    # hsa_core keeps its data inside the Python package (parameter sets, robot wiring, gains): share/hsa_core/config
    if [ -d "$ROOT/$p/$p/config" ]; then ln -sfn "$ROOT/$p/$p/config" "$V/share/$p/config"; fi
  done
  "$V/bin/python" - "$V" "${PACKAGES[@]}" <<'PY'
import sys
from importlib.metadata import distribution
from pathlib import Path

venv = Path(sys.argv[1])
for package in sys.argv[2:]:
    lib = venv / "lib" / package
    lib.mkdir(parents=True, exist_ok=True)
    for entry in distribution(package).entry_points.select(group="console_scripts"):
        if not (venv / "bin" / entry.name).is_file():
            sys.exit(f"[bootstrap] console script {entry.name} of {package} is missing from {venv / 'bin'}")
        link = lib / entry.name
        link.unlink(missing_ok=True)
        link.symlink_to(Path("../../bin") / entry.name)
PY
  mark pkgs "$pkg_hash"
fi

# 4. bytecode: uv installs without it (pip and colcon write it), and where PYTHONDONTWRITEBYTECODE is set nothing ever
#    writes it, so every process would compile each module it imports from source (importing JAX and rclpy: 2.2 s
#    instead of 0.8 s, benchmarks/results/startup.json). Python reads .pyc files whatever that variable says: the
#    dependencies are compiled once per install, our packages whenever a source is newer than the last pass. The
#    dependencies' own test suites (*/tests/, */test/: a fifth of their sources) are never imported here: not compiled.
if ! fresh bytecode "$req_hash$msg_hash"; then
  log "compiling the dependencies' bytecode (about 10 s)"
  site=$("$V/bin/python" -c "import sysconfig; print(sysconfig.get_paths()['purelib'])")
  "$V/bin/python" -m compileall -q -j 0 -x '/tests?/' "$site" > /dev/null 2>&1 || true  # some templates don't parse
  mark bytecode "$req_hash$msg_hash"
fi
sources=$(for p in "${PACKAGES[@]}"; do echo "$ROOT/$p/$p"; done)
if [ ! -f "$STAMPS/sources" ] || [ -n "$(find $sources -name '*.py' -newer "$STAMPS/sources" -print -quit)" ]; then
  touch "$STAMPS/sources.new"
  "$V/bin/python" -m compileall -q -j 0 $sources > /dev/null
  mv "$STAMPS/sources.new" "$STAMPS/sources"
fi
