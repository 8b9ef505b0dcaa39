#!/usr/bin/env bash
# Create .venv (once) and install navgym with its test, distributed (Ray) and RL Zoo extras. Idempotent:
# when .venv already has navgym and every requirement of pyproject.toml (with those extras) is satisfied,
# nothing is installed (SETUP_FORCE=1 reinstalls anyway).
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
if [ -z "${SETUP_FORCE:-}" ] && .venv/bin/python - <<'PYEOF' 2>/dev/null
import importlib.metadata as md, sys
try:
    import tomllib
except ImportError:
    import tomli as tomllib
from packaging.requirements import Requirement
p = tomllib.load(open("pyproject.toml", "rb"))["project"]
reqs = list(p["dependencies"]) + [r for e in ("dev", "distributed", "zoo") for r in p["optional-dependencies"][e]]
md.version("navgym")
for s in reqs:
    r = Requirement(s)
    if r.marker is not None and not r.marker.evaluate():
        continue
    if not r.specifier.contains(md.version(r.name), prereleases=True):
        sys.exit(1)
PYEOF
then
  echo "setup: .venv already satisfies pyproject.toml (SETUP_FORCE=1 reinstalls)"
  exit 0
fi
# torch first and pinned: the CPU wheel 2.13.0 (a bare 'torch' could pull a CUDA build).
.venv/bin/python -m pip install -q --upgrade pip >/dev/null 2>&1 || true
.venv/bin/python -m pip install -q "torch==2.13.0"
.venv/bin/python -m pip install -q -e ".[dev,distributed,zoo]"
