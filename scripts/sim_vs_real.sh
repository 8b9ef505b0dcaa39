#!/usr/bin/env bash
# The sim-vs-real note docs/sim-vs-real.md (issue 36): per elevation band, the simulated `urban` and
# `urban-transition` per-channel features (C/N0 of LOS / NLOS channels, C/N0 scatter about each data set's own
# elevation fit, truth residuals, NLOS share and dwell times, satellites per epoch) against the smartLoc Potsdamer
# Platz recording's (labels from its truth residuals), with two-sample KS distances. Under a minute on 2 cores
# (16 full-length episodes per scenario). Needs the recording in ../shared/data (or NAVGYM_DATA_DIR). Set PY to use
# another interpreter; extra arguments go to agents/sim_vs_real.py (--seeds, --seed, --out).
set -euo pipefail
cd "$(dirname "$0")/.."
if [ -z "${PY:-}" ]; then bash scripts/setup.sh; PY=.venv/bin/python; fi
$PY -m agents.sim_vs_real "$@"
