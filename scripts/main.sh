#!/usr/bin/env bash
# Set up (if needed) and run the main job: the default paired Monte Carlo comparison.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
.venv/bin/python eval.py "$@"
