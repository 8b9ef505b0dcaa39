#!/usr/bin/env bash
# The main job on a fresh clone: set up, train a small tuning policy (PPO, --quick), tune the optimized
# fixed forgetting factor on training seeds, and compare both with the hand-designed filters on held-out
# paired episodes. Outputs: runs/main/ (model, config, tuning.json), results/main/ (table, plots).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
PY=.venv/bin/python
ENV=GnssIns/SageHusa-v0
$PY train.py rl --env "$ENV" --algo ppo --quick --seed 0 --out runs/main
# tuned on full-length episodes, the distribution the evaluation uses (noise bursts start at 45 s)
$PY train.py tune --env "$ENV" --env-kwargs episode_length_s=300 --n-train 8 --seed 0 --out runs/main
$PY eval.py --scenario noise-burst --scenario urban --scenario open-sky \
  --methods "kf,sage-husa,stkf,ma-stkf,tuned:runs/main/tuning.json,ppo:runs/main/model.zip" \
  --reference "tuned:runs/main/tuning.json" --episodes "${EPISODES:-16}" --seed 0 --out results/main \
  --note results/main/NOTE.md "$@"
