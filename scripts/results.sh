#!/usr/bin/env bash
# The results note docs/results.md (issue 16): a learned forgetting-factor policy judged by the share of the
# knob headroom it closes, on the six scenarios of issue 16 (urban, urban-transition, noise-mismatch,
# regime-switch, noise-burst; open-sky as the placebo), whose definitions and headroom docs/headroom.md fixed
# before any learned evaluation. Per scenario: the optimized fixed Sage-Husa b tuned on 32 training episodes of
# 300 s; PPO trained with 3 seeds (150k env steps each, 64 rows of the native vector env, 300 s episodes: the sweep
# configs/results.yml); on urban-transition and open-sky also PPO with 4 stacked observation frames and the
# 'advantage' reward (configs/results_variants.yml) and RecurrentPPO (configs/results_recurrent.yml), 3 seeds
# each, the same budget; then eval.py --headroom on 50 held-out paired episodes with kf, sage-husa (b = 0.98),
# the group law, stkf, ma-stkf, the robust methods (vb-akf, kf-fde, kf-igg3, kf-huber, sage-husa+fde), the
# hand-designed rule and the oracles (--skip-missing leaves the variant and
# RecurrentPPO out of the scenarios they were not trained on, and the note lists where).
# About 2-3 hours on 2 CPU cores: PPO 3-4 min per run, RecurrentPPO ~10 min per run (WORKERS at once), tuning
# ~3 min per scenario, the evaluation ~30 min.
# Set PY to use another interpreter, RAY_ADDRESS=HOST:6379 to run on a Ray cluster, WORKERS for the Ray
# workers (default 2), SWEEP_BACKEND=local to train one run after another in this process (no Ray); finished
# runs are not redone (the sweep keeps finished trials; a failed one stops the script after the sweep table,
# runs/results/sweep.md, and a rerun retries it).
# SWEEP, SWEEP_VARIANTS, SWEEP_RECURRENT, EPISODES, N_TRAIN, RUNS, OUT and NOTE change the sweep files, the
# evaluation episodes, the tuning episodes and the output paths (defaults: the note's; a small check: EPISODES=2
# N_TRAIN=2 with small SWEEP files).
set -euo pipefail
cd "$(dirname "$0")/.."
if [ -z "${PY:-}" ]; then bash scripts/setup.sh; PY=.venv/bin/python; fi
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
ENV=GnssIns/SageHusa-v1
SCENARIOS="urban urban-transition noise-mismatch regime-switch noise-burst open-sky"
SWEEP=${SWEEP:-configs/results.yml}
SWEEP_VARIANTS=${SWEEP_VARIANTS:-configs/results_variants.yml}
SWEEP_RECURRENT=${SWEEP_RECURRENT:-configs/results_recurrent.yml}
EPISODES=${EPISODES:-50}
N_TRAIN=${N_TRAIN:-32}
RUNS=${RUNS:-runs/results}
OUT=${OUT:-results/results}
NOTE=${NOTE:-docs/results.md}
BACKEND=(--backend ray)
if [ -n "${RAY_ADDRESS:-}" ]; then BACKEND+=(--address "$RAY_ADDRESS"); else BACKEND+=(--workers "${WORKERS:-2}"); fi
if [ "${SWEEP_BACKEND:-ray}" = local ]; then TRAIN_BACKEND=(--backend local); else TRAIN_BACKEND=("${BACKEND[@]}"); fi
ARGS=()
for scen in $SCENARIOS; do
  if [ ! -f $RUNS/$scen/tuning.json ]; then
    $PY train.py tune --env $ENV --env-kwargs scenario=$scen episode_length_s=300 --n-train $N_TRAIN --seed 0 \
      --out $RUNS/$scen
  fi
  ARGS+=(--scenario "$scen")
done
for sweep in "$SWEEP" "$SWEEP_VARIANTS" "$SWEEP_RECURRENT"; do
  $PY train.py sweep --config "$sweep" --out $RUNS "${TRAIN_BACKEND[@]}"
done
K="$ENV[segment_s=10,lookahead_s=20,n=7]"
$PY eval.py "${ARGS[@]}" --episodes $EPISODES --seed 0 --headroom --goal -20 --goal open-sky=2 --skip-missing \
  --methods "tuned:$RUNS/{scenario}/tuning.json,kf,sage-husa,sage-husa-group,stkf,ma-stkf,vb-akf,kf-fde,kf-igg3,kf-huber,sage-husa+fde,rule:$ENV,ppo:$RUNS/{scenario}/ppo-s*/model.zip,ppo:$RUNS/{scenario}/ppo-h4adv-s*/model.zip,recurrentppo:$RUNS/{scenario}/recurrentppo-s*/model.zip,oracle-r,oracle-schedule:$K,crossfit-schedule:$K" \
  --reference "tuned:$RUNS/{scenario}/tuning.json" "${BACKEND[@]}" --out $OUT --note $NOTE
