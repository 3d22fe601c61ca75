#!/usr/bin/env bash
# Build and install the interface packages in msg_defs/ into the virtual environment's prefix with plain CMake,
# so that `from changing_slam_msgs.msg import Keyframe` works in the venv with nothing to source.
#
#   tools/build_interfaces.sh            # build if msg_defs/ changed since the last install, else return at once
#   tools/build_interfaces.sh --force    # rebuild regardless of the stamps
#   tools/build_interfaces.sh --check    # exit 0 when up to date, 1 when a build is needed
#
# Prefix: $VIRTUAL_ENV when set, else <repo>/.venv. Build trees: <repo>/build/interfaces/<package>.
# msg_defs/tf2_msgs_fallback (provides tf2_msgs/msg/TFMessage) is built only when no other tf2_msgs is
# importable: a real ROS 2 install keeps its own.
# Stamps, one per package, hold a hash of its msg_defs/ folder, this script and the prefix:
# $PREFIX/share/changing_slam_msgs/build_stamp and $PREFIX/share/tf2_msgs/changing_slam_fallback (the latter
# also marks the installed tf2_msgs as ours).
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
PREFIX="${VIRTUAL_ENV:-$ROOT/.venv}"
PY="$PREFIX/bin/python"
BUILD_ROOT="$ROOT/build/interfaces"
STAMP="$PREFIX/share/changing_slam_msgs/build_stamp"
FALLBACK_MARKER="$PREFIX/share/tf2_msgs/changing_slam_fallback"
MODE=build
case "${1:-}" in
  --force) MODE=force ;;
  --check) MODE=check ;;
  "") ;;
  *) echo "usage: tools/build_interfaces.sh [--force|--check]" >&2; exit 2 ;;
esac

if [[ ! -x "$PY" ]]; then
  echo "build_interfaces: no Python at $PY (create the venv first, or set VIRTUAL_ENV)" >&2
  exit 1
fi

# Hash of one package's sources, this script and the prefix: the package is rebuilt when it changes.
pkg_hash() {
  (
    cd "$ROOT"
    find "msg_defs/$1" -type f ! -name '*.pyc' -print0 | LC_ALL=C sort -z | xargs -0 sha256sum
    sha256sum tools/build_interfaces.sh
    echo "$PREFIX"
  ) | sha256sum | cut -d' ' -f1
}

# tf2_msgs: ours only where nothing else provides it (or where ours is the one installed).
want_fallback() {
  [[ -f "$FALLBACK_MARKER" ]] || ! "$PY" -c "import tf2_msgs.msg" >/dev/null 2>&1
}

up_to_date() {
  [[ -f "$STAMP" && "$(cat "$STAMP")" == "$(pkg_hash changing_slam_msgs)" ]] || return 1
  if want_fallback; then
    [[ -f "$FALLBACK_MARKER" && "$(cat "$FALLBACK_MARKER")" == "$(pkg_hash tf2_msgs_fallback)" ]] || return 1
  fi
  return 0
}

if [[ $MODE == check ]]; then
  up_to_date && { echo "build_interfaces: up to date"; exit 0; }
  echo "build_interfaces: out of date (run tools/build_interfaces.sh)"; exit 1
fi
if [[ $MODE == build ]] && up_to_date; then
  exit 0
fi

mkdir -p "$BUILD_ROOT"
# One build at a time (make run and make test may start together).
exec 9>"$BUILD_ROOT/.lock"
flock 9
if [[ $MODE == build ]] && up_to_date; then
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

if want_fallback; then
  if [[ $MODE == force || ! -f "$FALLBACK_MARKER" || "$(cat "$FALLBACK_MARKER")" != "$(pkg_hash tf2_msgs_fallback)" ]]; then
    mkdir -p "$(dirname "$FALLBACK_MARKER")"
    echo building > "$FALLBACK_MARKER"  # still ours while it builds; the hash is written on success
    build_one "$ROOT/msg_defs/tf2_msgs_fallback"
    # The marker says "this tf2_msgs is ours" and holds the hash it was built from.
    pkg_hash tf2_msgs_fallback > "$FALLBACK_MARKER"
  fi
else
  echo "build_interfaces: using the installed tf2_msgs"
fi
if [[ $MODE == force || ! -f "$STAMP" || "$(cat "$STAMP")" != "$(pkg_hash changing_slam_msgs)" ]]; then
  build_one "$ROOT/msg_defs/changing_slam_msgs"
  "$PY" -c "from changing_slam_msgs.msg import Keyframe; from tf2_msgs.msg import TFMessage" \
    || { echo "build_interfaces: installed, but the Python import check failed" >&2; exit 1; }
  pkg_hash changing_slam_msgs > "$STAMP"
fi
echo "build_interfaces: done in $(( $(date +%s) - start )) s"
