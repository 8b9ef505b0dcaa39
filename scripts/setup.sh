#!/usr/bin/env bash
# Create .venv (once) and install navgym with its test, distributed (Ray) and RL Zoo extras. Idempotent.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
# torch first and pinned: the CPU wheel 2.13.0 (a bare 'torch' could pull a CUDA build).
.venv/bin/python -m pip install -q --upgrade pip >/dev/null 2>&1 || true
.venv/bin/python -m pip install -q "torch==2.13.0"
.venv/bin/python -m pip install -q -e ".[dev,distributed,zoo]"
