#!/usr/bin/env bash
# The real-data table docs/real-data.md (issue "robust"): every shipped recording (smartLoc with the industrial
# synthesized IMU, smartLoc with a consumer IMU + its recorded wheel odometry, smartLoc GPS-only, the Reach static
# RINEX) through SPP, kf, the robust screens, every adaptive law and its +fde variant, and the real-data R oracle,
# with the replay consistency check and the published robust estimator's figures on smartLoc (quoted from
# ../shared/peers/librsf.md). About 10 minutes on 2 cores. Needs the recordings in ../shared/data (or
# NAVGYM_DATA_DIR). Set PY to use another interpreter; extra arguments go to agents/real_data.py (--episodes,
# --seed, --out, --quick).
set -euo pipefail
cd "$(dirname "$0")/.."
if [ -z "${PY:-}" ]; then bash scripts/setup.sh; PY=.venv/bin/python; fi
$PY -m agents.real_data "$@"
