#!/usr/bin/env bash
# Runs the test suite in the project's virtual environment (created or refreshed first).
#   bash scripts/test.sh           every tier (what CI runs)
#   bash scripts/test.sh --fast    all but the tests marked slow: every backend, a retry and a
#                                  ROS closed loop, in a few minutes
# Other arguments go to pytest, e.g. -m unit, -m "solve and not slow", -k name.
source "$(dirname "${BASH_SOURCE[0]}")/venv.sh"
args=()
for arg in "$@"; do
  if [ "$arg" = --fast ]; then args+=(-m "not slow"); else args+=("$arg"); fi
done
exec python -m pytest "${args[@]}"
