#!/usr/bin/env bash
# Builds bench/.venv-hj: hj_reachability 0.7.0 (StanfordASL's JAX level-set solver) with
# CPU jax, in a venv of its own so the package's .venv never depends on JAX.
# Used only by bench/bench_reach.py. Idempotent: re-running only checks the install.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
venv="$here/.venv-hj"
python="${PYTHON:-python3}"
if [ ! -x "$venv/bin/python" ]; then
    "$python" -m venv "$venv"
fi
"$venv/bin/python" -m pip install --quiet --upgrade pip
"$venv/bin/python" -m pip install --quiet "hj_reachability==0.7.0" jax jaxlib
"$venv/bin/python" - <<'PY'
import importlib.metadata as md
for name in ("hj_reachability", "jax", "jaxlib", "numpy"):
    print(f"{name}=={md.version(name)}")
PY
