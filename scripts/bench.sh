#!/usr/bin/env bash
# The benchmark, with its peers (do-mpc, rockit-meco) installed into .venv first.
source "$(dirname "${BASH_SOURCE[0]}")/venv.sh"
python -m pip install -q --disable-pip-version-check "do-mpc==5.1.2" "rockit-meco==0.6.7"
exec nh-tracking bench --out results/bench "$@"
