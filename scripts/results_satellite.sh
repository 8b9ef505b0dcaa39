#!/usr/bin/env bash
# docs/results-satellite.md (issue "per-satellite agent", part 5): the per-satellite learned methods against the
# best hand-designed method of each scenario, with the share of the gap to oracle-r they close.
# - Learned methods, all trained in simulation on urban-smartloc only (the scenario calibrated to smartLoc's
#   channels, docs/sim-vs-real.md) and evaluated zero-shot everywhere else:
#   PPO on GnssIns/SatelliteR-v0 over kf-huber (configs/satellite_r.yml), PPO on GnssIns/SatelliteSageHusa-v0
#   over sage-husa-r (configs/satellite_sage_husa.yml), 3 seeds x 300k env steps each; learned-r
#   (scripts/learned_r.sh's models, the seed with the best validation NLL).
# - Reference per scenario: its best hand-designed method, fixed before any learned method ran
#   (docs/headroom.md, docs/headroom-urban-smartloc.md, docs/real-data.md); every hand-designed method is in the
#   table, so a better one would show.
# - Then ships the best per-satellite policy (by its own training-time evaluation reward, not by these test
#   episodes) to pretrained/satellite-r/ and the learned-r model to pretrained/learned-r/.
# About 40 minutes of training on 2 cores (finished runs are kept) and 30 of evaluation. Set PY to use another
# interpreter, EPISODES / REAL_EPISODES for the episode counts (defaults 50 / 10), WORKERS for the training
# sweep's Ray workers (default 2).
set -euo pipefail
cd "$(dirname "$0")/.."
if [ -z "${PY:-}" ]; then bash scripts/setup.sh; PY=.venv/bin/python; fi
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
EPISODES=${EPISODES:-50}
REAL_EPISODES=${REAL_EPISODES:-10}
OUT=${OUT:-results/results-satellite}
NOTE=${NOTE:-docs/results-satellite.md}
[ -f runs/learned-r/urban-smartloc-0/model.pt ] || PY=$PY bash scripts/learned_r.sh
[ -f runs/headroom/urban/tuning.json ] || PY=$PY bash scripts/headroom.sh
for cfg in satellite_r satellite_sage_husa; do
  $PY train.py sweep --config configs/$cfg.yml --out runs/${cfg//_/-} --backend ray --workers "${WORKERS:-2}"
done
$PY -m agents.pretrained --out pretrained \
  --policies 'runs/satellite-r/urban-smartloc/ppo-s*' 'runs/satellite-sage-husa/urban-smartloc/ppo-s*' \
  --learned-r 'runs/learned-r/urban-smartloc-*'
HAND="kf,sage-husa,sage-husa-r,sage-husa-group,stkf,ma-stkf,vb-akf,kf-fde,kf-igg3,kf-huber,sage-husa+fde"
LEARNED="learned-r:pretrained/learned-r/model.pt,ppo:runs/satellite-r/urban-smartloc/ppo-s*/model.zip"
LEARNED="$LEARNED,ppo:runs/satellite-sage-husa/urban-smartloc/ppo-s*/model.zip"
run() {  # scenario, reference, episodes, extra hand-designed methods
  local m="$2" b
  for b in ${HAND//,/ }; do [ "$b" = "$2" ] || m="$m,$b"; done
  $PY eval.py --scenario "$1" --methods "$m$4,$LEARNED,oracle-r" --reference "$2" --episodes "$3" \
    --seed 4 --no-plots --backend ray --workers "${WORKERS:-2}" --out "$OUT/$1" --note "$OUT/$1/NOTE.md"
}
TUNED=",tuned:runs/headroom/{scenario}/tuning.json,rule:GnssIns/SageHusa-v1"
SIM="urban-smartloc:kf-huber urban:vb-akf urban-transition:vb-akf regime-switch:vb-akf noise-mismatch:stkf open-sky:kf"
REAL="smartloc-potsdamer-platz:vb-akf smartloc-potsdamer-platz-nhc:sage-husa-group+fde"
REAL="$REAL smartloc-potsdamer-platz-odometry:kf-igg3"
for sr in $SIM; do run "${sr%%:*}" "${sr#*:}" "$EPISODES" "$TUNED"; done
for sr in $REAL; do run "${sr%%:*}" "${sr#*:}" "$REAL_EPISODES" ""; done
DIAG=()
for sd in 0 1 2; do DIAG+=(--method "ppo SatelliteR s$sd=ppo:runs/satellite-r/urban-smartloc/ppo-s$sd/model.zip"); done
$PY -m agents.channel_diagnostics --out "$OUT/channel_diagnostics.json" "${DIAG[@]}" \
  --method "learned-r=learned-r:pretrained/learned-r/model.pt"
$PY -m agents.satellite_results --diagnostics "$OUT/channel_diagnostics.json" --out "$NOTE" --runs "$OUT" --scenarios ${SIM} ${REAL} \
  --configs configs/satellite_r.yml configs/satellite_sage_husa.yml --pretrained pretrained
