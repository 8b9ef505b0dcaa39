#!/usr/bin/env bash
# The results note docs/results.md (issue 16): a learned forgetting-factor policy judged by the share of the
# knob headroom it closes. Per scenario (urban-transition, the scenario of docs/headroom.md with a placebo-net
# knob headroom above 25% under the consensus law; open-sky as the placebo): the optimized fixed Sage-Husa b
# tuned on 32 training episodes of 300 s, PPO trained with 3 seeds (150k env steps each, 64 rows of the native
# vector env, 300 s episodes: the sweep configs/results.yml, run as Ray Tune trials, WORKERS at once), PPO with 4
# stacked observation frames and the 'advantage' reward, 3 seeds (configs/results_variants.yml, the same budget),
# then eval.py --headroom on 50 held-out paired episodes with kf, sage-husa (b = 0.98), the group law, stkf,
# ma-stkf, the hand-designed rule, and the oracles, its batches as Ray tasks (issue 14). About an hour on 2 CPU
# cores (measured with the runs one after another: training 2.6-3.2 min per PPO run at 820-950 env-steps/s,
# tuning 2 x 80 s, eval below).
# Set PY to use another interpreter, RAY_ADDRESS=HOST:6379 to run on a Ray cluster, WORKERS for the Ray
# workers (default 2); finished runs are not redone (the sweep keeps finished trials; a failed one stops the
# script after the sweep table, runs/results/sweep.md, and a rerun retries it).
# SWEEP, SWEEP_VARIANTS, EPISODES, N_TRAIN, RUNS, OUT and NOTE change the sweep files, the evaluation episodes, the tuning
# episodes and the output paths (defaults: the note's; a small check: EPISODES=2 N_TRAIN=2 with a small SWEEP).
set -euo pipefail
cd "$(dirname "$0")/.."
if [ -z "${PY:-}" ]; then bash scripts/setup.sh; PY=.venv/bin/python; fi
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
ENV=GnssIns/SageHusa-v0
SCENARIOS="urban-transition open-sky"
SWEEP=${SWEEP:-configs/results.yml}
SWEEP_VARIANTS=${SWEEP_VARIANTS:-configs/results_variants.yml}
EPISODES=${EPISODES:-50}
N_TRAIN=${N_TRAIN:-32}
RUNS=${RUNS:-runs/results}
OUT=${OUT:-results/results}
NOTE=${NOTE:-docs/results.md}
BACKEND=(--backend ray)
if [ -n "${RAY_ADDRESS:-}" ]; then BACKEND+=(--address "$RAY_ADDRESS"); else BACKEND+=(--workers "${WORKERS:-2}"); fi
ARGS=()
for scen in $SCENARIOS; do
  if [ ! -f $RUNS/$scen/tuning.json ]; then
    $PY train.py tune --env $ENV --env-kwargs scenario=$scen episode_length_s=300 --n-train $N_TRAIN --seed 0 \
      --out $RUNS/$scen
  fi
  ARGS+=(--scenario "$scen")
done
$PY train.py sweep --config "$SWEEP" --out $RUNS "${BACKEND[@]}"
$PY train.py sweep --config "$SWEEP_VARIANTS" --out $RUNS "${BACKEND[@]}"
K="$ENV[segment_s=10,lookahead_s=20,n=7]"
$PY eval.py "${ARGS[@]}" --episodes $EPISODES --seed 0 --headroom --goal -20 --goal open-sky=2 \
  --methods "tuned:$RUNS/{scenario}/tuning.json,kf,sage-husa,sage-husa-group,stkf,ma-stkf,rule:$ENV,ppo:$RUNS/{scenario}/ppo-s*/model.zip,ppo:$RUNS/{scenario}/ppo-h4adv-s*/model.zip,oracle-r,oracle-schedule:$K,crossfit-schedule:$K" \
  --reference "tuned:$RUNS/{scenario}/tuning.json" "${BACKEND[@]}" --out $OUT --note $NOTE
