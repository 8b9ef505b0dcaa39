#!/usr/bin/env bash
# The main job on a fresh clone: set up, train a small tuning policy (PPO, --quick), tune the optimized
# fixed forgetting factor on training seeds of each evaluated scenario, and compare both with the
# hand-designed filters on held-out paired episodes, the best robust ones included (kf-igg3, vb-akf,
# sage-husa+fde: a learned method is judged against the best hand-designed one, not a straw man).
# Outputs: runs/main/ (model, config.json, tune-<scenario>/tuning.json), results/main/ (table, plots, NOTE.md);
# python scripts/readme_results.py then puts the table and one plot into README.md.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
PY=.venv/bin/python
ENV=GnssIns/SageHusa-v1
SCENARIOS=(noise-burst urban open-sky)
$PY train.py rl --env "$ENV" --algo ppo --quick --seed 0 --out runs/main
# the optimized fixed b per evaluated scenario, on full-length training episodes (the distribution the
# evaluation uses: noise bursts start at 45 s); eval.py picks runs/main/tune-<scenario>/ by '{scenario}'
for s in "${SCENARIOS[@]}"; do
  $PY train.py tune --env "$ENV" --env-kwargs scenario="$s" episode_length_s=300 --n-train 8 --seed 0 \
    --out "runs/main/tune-$s"
done
TUNED="tuned:runs/main/tune-{scenario}/tuning.json"
$PY eval.py "${SCENARIOS[@]/#/--scenario=}" \
  --methods "kf,sage-husa,stkf,ma-stkf,kf-igg3,vb-akf,sage-husa+fde,$TUNED,ppo:runs/main/model.zip" \
  --reference "$TUNED" --episodes "${EPISODES:-16}" --seed 0 --out results/main \
  --note results/main/NOTE.md "$@"
