#!/usr/bin/env bash
# One command: set up .venv (if needed) and run the whole test suite.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$root/scripts/setup.sh"
source "$root/scripts/ros-env.sh"
cd "$root"
exec .venv/bin/python -m pytest -q -rs "$@" test   # -rs: every skip says why
