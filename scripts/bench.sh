#!/usr/bin/env bash
# The benchmark, with do-mpc (the optional 'bench' extra) as the peer it is compared against.
source "$(dirname "${BASH_SOURCE[0]}")/venv.sh"
python -m pip install -q --disable-pip-version-check "do-mpc==5.1.2"
exec nh-tracking bench --out results/bench "$@"
