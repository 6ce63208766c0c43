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

# the console's browser tests drive headless Chromium from Debian (no downloads at run time)
if ! command -v chromium >/dev/null 2>&1 || ! command -v chromedriver >/dev/null 2>&1; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "setup: installing chromium and chromium-driver (Debian packages, for the console's browser tests)"
    DEBIAN_FRONTEND=noninteractive apt-get install -y chromium chromium-driver >/dev/null \
      || { apt-get update >/dev/null && DEBIAN_FRONTEND=noninteractive apt-get install -y chromium chromium-driver >/dev/null; } \
      || echo "setup: could not install chromium/chromium-driver; the console's browser tests need them" >&2
  else
    echo "setup: chromium/chromedriver missing; as root: apt-get install -y chromium chromium-driver" >&2
  fi
fi

stamp_src="$(cat requirements.txt setup.py setup.cfg package.xml | sha256sum | cut -d' ' -f1)"
if [ -x .venv/bin/python ] && [ -f .venv/.supersafe-stamp ] && [ "$(cat .venv/.supersafe-stamp)" = "$stamp_src" ]; then
  exit 0
fi
if [ ! -x .venv/bin/python ]; then
  echo "setup: creating .venv with $($py --version 2>&1)"
  "$py" -m venv .venv || { echo "setup: '$py -m venv' failed (on Debian: apt-get install python3-venv)" >&2; exit 1; }
fi
echo "setup: installing dependencies (ROS 2 Jazzy wheels, numpy, scipy, matplotlib, pytest)"
# pip's own warnings about this machine's extra package indexes are noise here
quiet_pip() { .venv/bin/python -m pip install --quiet --disable-pip-version-check "$@" 2>&1 \
  | { grep -v -e "is ignored: it is neither a file nor a directory" -e BuildBackendWarning || true; }; }
quiet_pip --upgrade pip
quiet_pip -r requirements.txt
quiet_pip --no-deps -e .
.venv/bin/python -c "import rclpy, numpy, scipy, supersafe_ros" \
  || { echo "setup: the environment is incomplete (see the pip output above)" >&2; exit 1; }
echo "$stamp_src" > .venv/.supersafe-stamp
echo "setup: ready ($(.venv/bin/python --version), console scripts in .venv/bin)"
