#!/usr/bin/env bash
# The main job: runs the demo in the project's virtual environment (created or refreshed first).
source "$(dirname "${BASH_SOURCE[0]}")/venv.sh"
exec nh-tracking demo --out results/demo "$@"
