#!/usr/bin/env bash
# `make demo`: the main job end to end on the default configuration (after `make build`):
#   1. collect demonstrations: the expert (fast_planner + its C++ collector) flies seeded worlds on the rollout
#      engine, 2 worker threads (python -m quad_il.collection.parallel; the records collect.launch would write);
#   2. train the policy on them (training_only/train_on_cpp_datasets.py; exports policy.ts);
#   3. offline evaluation on demonstrations from worlds never seen in training (training_only/evaluate_policy.py);
#   4. closed-loop evaluation on the engine: the expert and the C++ (LibTorch) policy fly the same held-out
#      episodes (python -m quad_il.evaluation.run_eval) in the `shield` tier, and the policy again in the
#      `bare` tier (the network alone, docs/inference.md "Tiers"); Markdown reports with plots. (The Python
#      node flies on the ROS backend: make eval BACKEND=ros.)
#   5. the shipped policy (models/quad_il_policy, its MODEL.md) flies the same episodes in the `bare` tier, and
#      the two networks alone are compared episode by episode (python -m quad_il.evaluation.compare).
# Every stage's output is under $OUT (default results/demo); a stage whose output is complete is skipped, so an
# interrupted demo continues where it stopped (DEMO_FRESH=1 starts over). Larger settings by variables:
#   DEMO_TRAIN_EPISODES (60) DEMO_TEST_EPISODES (12) DEMO_EPOCHS (12) DEMO_EVAL_EPISODES (20) DEMO_WORKERS (2)
#   DEMO_TRAIN_ARGS (train_on_cpp_datasets.py arguments; default: state and output in the vehicle's local frame
#   and the rate decayed over the run, the recipe of the trained policy in docs/RESULTS.md; on synthetic data
#   the local frame reached a far lower validation loss than the thesis's world frame, docs/scaling.md)
# The closed loop flies the policy nodes with run_eval's default config, config/policy.yaml (infer.launch's too).
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$ROOT"
# shellcheck disable=SC1091
source scripts/env.sh
OUT=${OUT:-$ROOT/results/demo}
TRAIN_EPISODES=${DEMO_TRAIN_EPISODES:-60}
TEST_EPISODES=${DEMO_TEST_EPISODES:-12}
EPOCHS=${DEMO_EPOCHS:-12}
EVAL_EPISODES=${DEMO_EVAL_EPISODES:-20}
SHIPPED=models/quad_il_policy/policy.ts
WORKERS=${DEMO_WORKERS:-2}
[ "${DEMO_FRESH:-0}" = 1 ] && rm -rf "$OUT"
mkdir -p "$OUT"
t_start=$(date +%s)
stage() { echo "[demo] $(($(date +%s) - t_start)) s: $*"; }

collect() {  # name seeds episodes
  local dir="$OUT/data/$1"
  if [ -f "$dir/collection.yaml" ]; then
    stage "collection $1 already done ($dir)"
    return
  fi
  rm -rf "$dir"
  python -m quad_il.collection.parallel --workers "$WORKERS" --seeds "$2" --episodes "$3" --out "$dir"
}

stage "1/5 collecting $TRAIN_EPISODES training episodes (world seeds 100-...) and $TEST_EPISODES held-out ones (seeds 7000-...)"
collect train "100-$((100 + TRAIN_EPISODES - 1))" "$TRAIN_EPISODES"
collect heldout "7000-$((7000 + TEST_EPISODES - 1))" "$TEST_EPISODES"

RUN="$OUT/runs/policy"
if [ -f "$RUN/policy.ts" ]; then
  stage "2/5 policy already trained ($RUN/policy.ts)"
else
  stage "2/5 training ($EPOCHS epochs; progress below)"
  rm -rf "$RUN"
  # shellcheck disable=SC2086
  python training_only/train_on_cpp_datasets.py --config config/train.yaml --data "$OUT/data/train" \
    --out "$OUT/runs" --name policy --epochs "$EPOCHS" \
    ${DEMO_TRAIN_ARGS:---set model.state_frame=local --set model.output_frame=local --set scheduler.name=cosine}
fi

stage "3/5 offline evaluation on the held-out demonstrations"
python training_only/evaluate_policy.py --policy "$RUN" --data "$OUT/data/heldout" --out "$OUT/offline"

stage "4/5 closed-loop evaluation on the engine: expert and C++ policy on $EVAL_EPISODES held-out episodes"
EVAL_SEEDS="9000-$((9000 + EVAL_EPISODES - 1))"
python -m quad_il.evaluation.run_eval --policy "$RUN/policy.ts" --seeds "$EVAL_SEEDS" \
  --episodes "$EVAL_EPISODES" --out "$OUT/eval"
# The network alone on the same episodes: a hand-written behaviour's success is never the network's.
python -m quad_il.evaluation.run_eval --policy "$RUN/policy.ts" --seeds "$EVAL_SEEDS" \
  --episodes "$EVAL_EPISODES" --tier bare --controllers cpp --out "$OUT/eval_bare"

stage "5/5 the shipped policy ($SHIPPED) alone on the same episodes, beside the demo's own"
python -m quad_il.evaluation.run_eval --policy "$SHIPPED" --seeds "$EVAL_SEEDS" \
  --episodes "$EVAL_EPISODES" --tier bare --controllers cpp --out "$OUT/eval_shipped_bare"
python -m quad_il.evaluation.compare "$OUT/eval_bare" "$OUT/eval_shipped_bare" --out "$OUT/own_vs_shipped.md"

stage "done"
echo "[demo] training data:        $OUT/data/train/collection.yaml"
echo "[demo] trained policy:       $RUN (loss curves: $RUN/loss_curves.png)"
echo "[demo] offline metrics:      $OUT/offline/summary.md"
echo "[demo] closed-loop report:   $OUT/eval/report.md (tier shield), $OUT/eval_bare/report.md (tier bare)"
echo "[demo] shipped policy, bare: $OUT/eval_shipped_bare/report.md; own vs shipped: $OUT/own_vs_shipped.md"
