#!/usr/bin/env bash
# Runs the test suite in the project's virtual environment (created or refreshed first).
source "$(dirname "${BASH_SOURCE[0]}")/venv.sh"
exec python -m pytest "$@"
