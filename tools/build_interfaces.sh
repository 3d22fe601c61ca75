#!/usr/bin/env bash
# Build and install the interface packages in msg_defs/ into the virtual environment's prefix with plain CMake,
# so that `from changing_slam_msgs.msg import Keyframe` works in the venv with nothing to source.
#
#   tools/build_interfaces.sh            # build if msg_defs/ changed since the last install, else return at once
#   tools/build_interfaces.sh --force    # rebuild regardless of the stamp
#
# Prefix: $VIRTUAL_ENV when set, else <repo>/.venv. Build trees: <repo>/build/interfaces/<package>.
# msg_defs/tf2_msgs_fallback (provides tf2_msgs/msg/TFMessage) is built only when no other tf2_msgs is
# importable: a real ROS 2 install keeps its own.
# The stamp ($PREFIX/share/changing_slam_msgs/build_stamp) holds a hash of msg_defs/, this script and the prefix.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
PREFIX="${VIRTUAL_ENV:-$ROOT/.venv}"
PY="$PREFIX/bin/python"
BUILD_ROOT="$ROOT/build/interfaces"
STAMP="$PREFIX/share/changing_slam_msgs/build_stamp"
FALLBACK_MARKER="$PREFIX/share/tf2_msgs/changing_slam_fallback"
FORCE=0
[[ "${1:-}" == "--force" ]] && FORCE=1

if [[ ! -x "$PY" ]]; then
  echo "build_interfaces: no Python at $PY (create the venv first, or set VIRTUAL_ENV)" >&2
  exit 1
fi

hash_inputs() {
  (
    cd "$ROOT"
    find msg_defs -type f ! -name '*.pyc' -print0 | LC_ALL=C sort -z | xargs -0 sha256sum
    sha256sum tools/build_interfaces.sh
    echo "$PREFIX"
  ) | sha256sum | cut -d' ' -f1
}

WANT="$(hash_inputs)"
if [[ $FORCE -eq 0 && -f "$STAMP" && "$(cat "$STAMP")" == "$WANT" ]]; then
  exit 0
fi

mkdir -p "$BUILD_ROOT"
# One build at a time (make run and make test may start together).
exec 9>"$BUILD_ROOT/.lock"
flock 9
if [[ $FORCE -eq 0 && -f "$STAMP" && "$(cat "$STAMP")" == "$WANT" ]]; then
  exit 0
fi

for tool in cmake make g++; do
  command -v "$tool" >/dev/null || { echo "build_interfaces: '$tool' not found (apt-get install cmake g++ make)" >&2; exit 1; }
done

build_one() {
  local pkg_dir="$1" build_dir="$BUILD_ROOT/$(basename "$1")"
  echo "build_interfaces: building $(basename "$pkg_dir") into $PREFIX"
  cmake -S "$pkg_dir" -B "$build_dir" \
    -DCMAKE_INSTALL_PREFIX="$PREFIX" \
    -DCMAKE_PREFIX_PATH="$PREFIX" \
    -DCMAKE_BUILD_TYPE=Release \
    -DBUILD_TESTING=OFF \
    -DPython3_EXECUTABLE="$PY" \
    -DPYTHON_EXECUTABLE="$PY" \
    -DPython3_FIND_VIRTUALENV=ONLY \
    > "$build_dir.log" 2>&1 || { tail -n 40 "$build_dir.log" >&2; echo "build_interfaces: configure failed, log: $build_dir.log" >&2; exit 1; }
  cmake --build "$build_dir" -j "$(nproc)" >> "$build_dir.log" 2>&1 \
    || { tail -n 40 "$build_dir.log" >&2; echo "build_interfaces: build failed, log: $build_dir.log" >&2; exit 1; }
  cmake --install "$build_dir" >> "$build_dir.log" 2>&1 \
    || { tail -n 40 "$build_dir.log" >&2; echo "build_interfaces: install failed, log: $build_dir.log" >&2; exit 1; }
}

start=$(date +%s)
export AMENT_PREFIX_PATH="$PREFIX${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"

# tf2_msgs: ours only where nothing else provides it (or where ours is the one installed).
if [[ -f "$FALLBACK_MARKER" ]] || ! "$PY" -c "import tf2_msgs.msg" >/dev/null 2>&1; then
  build_one "$ROOT/msg_defs/tf2_msgs_fallback"
  echo "tf2_msgs/msg/TFMessage built by changing_slam_ros tools/build_interfaces.sh" > "$FALLBACK_MARKER"
else
  echo "build_interfaces: using the installed tf2_msgs"
fi
build_one "$ROOT/msg_defs/changing_slam_msgs"

"$PY" -c "from changing_slam_msgs.msg import Keyframe; from tf2_msgs.msg import TFMessage" \
  || { echo "build_interfaces: installed, but the Python import check failed" >&2; exit 1; }
echo "$WANT" > "$STAMP"
echo "build_interfaces: done in $(( $(date +%s) - start )) s"
