#!/usr/bin/env bash
# Build .venv in the repository root from nothing: ROS 2 Jazzy from PyPI wheels,
# numpy/scipy/matplotlib/pytest, and supersafe_ros itself (editable, console
# scripts in .venv/bin). Re-running is cheap: it skips when nothing changed.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
py="${PYTHON:-}"
if [ -z "$py" ]; then
  for cand in python3.11 python3; do
    if command -v "$cand" >/dev/null 2>&1; then py="$cand"; break; fi
  done
fi
[ -n "$py" ] || { echo "setup: no python3 found (Python 3.11 wanted: apt-get install python3 python3-venv)" >&2; exit 1; }

stamp_src="$(cat requirements.txt setup.py setup.cfg package.xml | sha256sum | cut -d' ' -f1)"
if [ -x .venv/bin/python ] && [ -f .venv/.supersafe-stamp ] && [ "$(cat .venv/.supersafe-stamp)" = "$stamp_src" ]; then
  exit 0
fi
if [ ! -x .venv/bin/python ]; then
  echo "setup: creating .venv with $($py --version 2>&1)"
  "$py" -m venv .venv || { echo "setup: '$py -m venv' failed (on Debian: apt-get install python3-venv)" >&2; exit 1; }
fi
echo "setup: installing dependencies (ROS 2 Jazzy wheels, numpy, scipy, matplotlib, pytest)"
.venv/bin/python -m pip install --quiet --upgrade pip
.venv/bin/python -m pip install --quiet -r requirements.txt
.venv/bin/python -m pip install --quiet --no-deps -e .
echo "$stamp_src" > .venv/.supersafe-stamp
echo "setup: ready ($(.venv/bin/python --version), console scripts in .venv/bin)"
