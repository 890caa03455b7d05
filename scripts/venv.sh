# Sourced by the other scripts: creates or refreshes .venv, then activates it.
# Reinstalls only when the pins or the packaging files change, so repeated runs start fast.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="$root/.venv"
python="${PYTHON:-python3}"
if [ ! -x "$venv/bin/python" ]; then
  echo "creating virtual environment in $venv" >&2
  "$python" -m venv "$venv"
fi
stamp="$venv/.nh_tracking-installed"
want="$(cat "$root/requirements.txt" "$root/setup.py" "$root/setup.cfg" "$root/package.xml" "$root/scripts/venv.sh" | sha256sum)"
if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
  echo "installing pinned dependencies into $venv" >&2
  "$venv/bin/python" -m pip install -q --disable-pip-version-check pip==26.3 setuptools==68.2.2 wheel==0.43.0
  "$venv/bin/python" -m pip install -q --disable-pip-version-check -r "$root/requirements.txt"
  "$venv/bin/python" -m pip install -q --disable-pip-version-check --no-build-isolation --no-deps -e "$root"
  echo "$want" > "$stamp"
fi
# nav2_msgs and tf2_msgs have no wheels: built from interfaces/ into the venv (stamp-guarded)
bash "$root/scripts/interfaces.sh" "$venv"
# shellcheck disable=SC1091
source "$venv/bin/activate"
# Keep ROS traffic on this machine: tests and demos must not talk to other hosts' nodes.
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
export MPLBACKEND=Agg
cd "$root"
