#!/usr/bin/env bash
# Builds the interface stand-ins of interfaces/ (nav2_msgs, tf2_msgs) into a venv: there are no
# wheels of them on the package registry. Usage: interfaces.sh VENV. Stamp-guarded: a rerun with
# the same definitions and pins does nothing. cmake, make and g++ come with the machine.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="$1"
stamp="$venv/.nh_tracking-interfaces"
want="$(cd "$root" && cat requirements.txt scripts/interfaces.sh $(find interfaces -type f | sort) | sha256sum)"
if [ "$(cat "$stamp" 2>/dev/null)" = "$want" ]; then
  exit 0
fi
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
for package in tf2_msgs nav2_msgs; do
  echo "building the interface stand-in $package into $venv" >&2
  # AMENT_PREFIX_PATH names the venv, where the wheels put the ROS packages' share/ folders
  if ! AMENT_PREFIX_PATH="$venv" PATH="$venv/bin:$PATH" cmake -S "$root/interfaces/$package" \
        -B "$work/$package" -DCMAKE_INSTALL_PREFIX="$venv" -DBUILD_TESTING=OFF \
        -DPython3_EXECUTABLE="$venv/bin/python" -DCMAKE_BUILD_TYPE=Release \
        >"$work/$package.log" 2>&1 \
     || ! AMENT_PREFIX_PATH="$venv" cmake --build "$work/$package" -j 2 >>"$work/$package.log" 2>&1 \
     || ! cmake --install "$work/$package" >>"$work/$package.log" 2>&1; then
    tail -n 40 "$work/$package.log" >&2
    echo "building the interface stand-in $package failed (log above)" >&2
    exit 1
  fi
done
echo "$want" > "$stamp"
