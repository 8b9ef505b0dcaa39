#!/usr/bin/env bash
# The results note docs/results.md (issue 5): per scenario (noise-burst, urban, open-sky), the optimized
# fixed Sage-Husa b tuned on 64 training episodes of 300 s, PPO trained with 3 seeds (300k env steps each,
# 120 s episodes), then eval.py on 50 held-out paired episodes against the optimized fixed b, with
# sage-husa (b = 0.98) and ma-stkf. About 45 minutes on 2 CPU cores. Set PY to use another interpreter.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ -z "${PY:-}" ]; then bash scripts/setup.sh; PY=.venv/bin/python; fi
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
ENV=GnssIns/SageHusa-v0
SCENARIOS="noise-burst urban open-sky"
for scen in $SCENARIOS; do
  $PY train.py tune --env $ENV --env-kwargs scenario=$scen episode_length_s=300 --n-train 64 --seed 0 \
    --out runs/results/$scen
done
for scen in $SCENARIOS; do
  for s in 0 1 2; do
    $PY train.py rl --env $ENV --algo ppo --timesteps 300000 --seed $s --env-kwargs scenario=$scen \
      --out runs/results/$scen/ppo-s$s
  done
done
$PY eval.py --scenario noise-burst --scenario urban --scenario open-sky --episodes 50 --seed 0 \
  --methods "tuned:runs/results/{scenario}/tuning.json,sage-husa,ma-stkf,ppo:runs/results/{scenario}/ppo-s*/model.zip" \
  --reference "tuned:runs/results/{scenario}/tuning.json" --goal -20 --goal open-sky=2 --out results/results --note docs/results.md
