#!/usr/bin/env bash
# The results note docs/results.md (issue 16): a learned forgetting-factor policy judged by the share of the
# knob headroom it closes. Per scenario (urban-transition and regime-switch, the two scenarios of
# docs/headroom.md with a knob headroom; open-sky as the placebo): the optimized fixed Sage-Husa b tuned on 32
# training episodes of 300 s, PPO trained with 3 seeds (200k env steps each, 64 rows of the native vector
# env, 300 s episodes), then eval.py --headroom on 50 held-out paired episodes with kf, sage-husa (b = 0.98),
# the group law, ma-stkf, the hand-designed rule, and the oracles. About 1 hour on 2 CPU cores (measured:
# training 4-9 min per run, tuning 3 x 45 s, eval 13 min). Set PY to use another interpreter; finished runs are not redone.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ -z "${PY:-}" ]; then bash scripts/setup.sh; PY=.venv/bin/python; fi
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
ENV=GnssIns/SageHusa-v0
SCENARIOS="urban-transition regime-switch open-sky"
ARGS=()
for scen in $SCENARIOS; do
  if [ ! -f runs/results/$scen/tuning.json ]; then
    $PY train.py tune --env $ENV --env-kwargs scenario=$scen episode_length_s=300 --n-train 32 --seed 0 \
      --out runs/results/$scen
  fi
  for s in 0 1 2; do
    if [ ! -f runs/results/$scen/ppo-s$s/model.zip ]; then
      $PY train.py rl --env $ENV --algo ppo --timesteps 200000 --n-envs 64 --seed $s \
        --env-kwargs scenario=$scen episode_length_s=300 --no-progress --out runs/results/$scen/ppo-s$s
    fi
  done
  ARGS+=(--scenario "$scen")
done
K="$ENV[segment_s=10,lookahead_s=20,n=7]"
$PY eval.py "${ARGS[@]}" --episodes 50 --seed 0 --headroom --goal -20 --goal open-sky=2 \
  --methods "tuned:runs/results/{scenario}/tuning.json,kf,sage-husa,sage-husa-group,ma-stkf,rule:$ENV,ppo:runs/results/{scenario}/ppo-s*/model.zip,oracle-r,oracle-schedule:$K,crossfit-schedule:$K" \
  --reference "tuned:runs/results/{scenario}/tuning.json" --out results/results --note docs/results.md
