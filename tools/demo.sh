#!/usr/bin/env bash
# The README's main job, on the default gap scenario (ciml_sim/config/scenarios/default_gap.yaml):
#   simulate + record -> extract -> learn -> closed loop (nominal / learned / identified)
#   -> diagnose -> report.
# Everything goes to out/demo/. The bags are recorded WITHOUT ground truth: the diagnosis
# sees only what a real robot's log would hold.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
CIML=.venv/bin/ciml
OUT=out/demo
SCENARIO=ciml_sim/config/scenarios/default_gap.yaml
rm -rf "$OUT"; mkdir -p "$OUT/bags"
step() { printf '\n==> [demo %s] %s\n' "$(date +%H:%M:%S)" "$*"; }

step "1/6 simulate and record training motions (base-only, walk 35 cm, trot 35 cm; 3 runs each) and held-out motions"
TRAIN=(); HELD=()
for motion in base_only walk_35 trot_35; do
  for seed in 1 2 3; do
    $CIML record --scenario "$SCENARIO" --motion "$motion" --duration 20 --seed "$seed" \
      --no-ground-truth --out "$OUT/bags/train_${motion}_$seed"
    TRAIN+=("$OUT/bags/train_${motion}_$seed")
  done
done
for spec in walk_20:24:11 trot_20:12:12; do
  IFS=: read -r motion dur seed <<<"$spec"
  $CIML record --scenario "$SCENARIO" --motion "$motion" --duration "$dur" --seed "$seed" \
    --no-ground-truth --out "$OUT/bags/heldout_$motion"
  HELD+=("$OUT/bags/heldout_$motion")
done

step "2/6 extract contact-invariant model errors"
$CIML extract --bag "${TRAIN[@]}" --out "$OUT/targets.npz"

step "3/6 learn the model error (sparse GP) and evaluate it on the held-out motions"
$CIML train --bag "${TRAIN[@]}" --learner sgpr --out "$OUT/model_sgpr"
$CIML evaluate --model "$OUT/model_sgpr" --bag "${HELD[@]}" --out "$OUT/evaluate_sgpr.json"

step "4/6 diagnose the sim-to-real gap (where, which effect, how far it shrinks)"
$CIML diagnose --bag "${TRAIN[@]}" --heldout "${HELD[@]}" --out "$OUT/diagnosis"

step "5/6 closed loop on a new execution of trot 35 cm: nominal vs learned vs identified"
for model in nominal "$OUT/model_sgpr" "$OUT/diagnosis"; do
  name=$(basename "$model")
  $CIML closed-loop --scenario "$SCENARIO" --motion trot_35 --duration 8 --seed 21 \
    --model "$model" --out "$OUT/closed_loop_$name.json" --report "$OUT/diagnosis"
done

step "6/6 report"
.venv/bin/python tools/demo_summary.py "$OUT"
