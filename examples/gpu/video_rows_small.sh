#!/usr/bin/env bash
# The video-prediction rows that need a GPU at `small`: Table 4's pixel-space predictors, one after another
# (packing them on one GPU gained nothing: results/gpu_h200/README.md, 2026-11-27), seed 0, through `reproduce` so the records are the
# plan's. Resumable: a second call on the same warm machine continues from the checkpoints (every 500 steps).
#
#   NO_GSPLAT=1 source examples/gpu/device_setup.sh || exit 1; PREDICTORS=simvp LIMIT=520 bash examples/gpu/video_rows_small.sh
#   DEVICE=cpu PREDICTORS=simvp EXTRA="--set video_config.simvp.train_steps=2" bash examples/gpu/video_rows_small.sh  # plumbing, on a CPU
#
# PREDICTORS (default "simvp mau") are plugin names; TABLE is table4_dvc (single-trajectory, Table 4) or table_dvc_multi
# (trained on several trajectories); LIMIT (seconds) stops training in time to pack the records. Writes to $OUT
# (default video-rows; DATA_ROOT, default $WORK/data, where the dataset is made or found): the log, the run records (result.json, tables, grids; no checkpoints) as records.tar, and the
# tables of what finished. On one H200 (2026-11-27): SimVP 0.137 s a step (3,000 steps: 411 s), MAU 0.331 s (993 s).
set -uo pipefail
OUT=${OUT:-video-rows}
DEVICE=${DEVICE:-cuda}
PREDICTORS=${PREDICTORS:-simvp mau}
TABLE=${TABLE:-table4_dvc}
LIMIT=${LIMIT:-540}
WORK=${WORK:-/tmp/video-rows}
DATA_ROOT=${DATA_ROOT:-$WORK/data}
mkdir -p "$OUT" "$WORK"
case $TABLE in
  table4_dvc) task=dvc; title="Table 4: cloth dynamic video prediction" ;;
  table_dvc_multi) task=dvc_multi; title="Video prediction trained on multiple trajectories (paper appendix)" ;;
  *) echo "video_rows_small: TABLE must be table4_dvc or table_dvc_multi, not '$TABLE'" >&2; exit 2 ;;
esac
plan=$WORK/plan.yaml
{
  echo "version: 1"
  echo "description: 'small, seed 0: $TABLE rows of $PREDICTORS on $DEVICE (examples/gpu/video_rows_small.sh)'"
  echo "tables:"
  echo "- {id: $TABLE, task: $task, title: '$title'}"
  echo "runs:"
  for p in $PREDICTORS; do
    case $p in simvp) label=SimVP ;; tau) label=TAU ;; mau) label=MAU ;; mmvp) label=MMVP ;; *) label=$p ;; esac
    echo "- {table: $TABLE, task: $task, label: $label, predictor: $p}"
  done
} > "$plan"
sets=(--set runs_dir="$WORK/runs" --set data.root="$DATA_ROOT")
for p in $PREDICTORS; do sets+=(--set "video_config.$p.device=$DEVICE"); done
# shellcheck disable=SC2206
extra=(${EXTRA:-})
log=$OUT/log.txt
echo "start $(date +%T), limit $LIMIT s" | tee -a "$log"
left=$((LIMIT - SECONDS - 20))
timeout -k 10 -s INT "$left" clods-bench reproduce --preset small --plan "$plan" --first-seeds 1 --jobs 1 --no-progress \
  --out "$WORK/tables" "${sets[@]}" "${extra[@]}" 2>&1 | tee -a "$log"
echo "reproduce rc=${PIPESTATUS[0]} at $SECONDS s" | tee -a "$log"
(cd "$WORK" && find runs -type f -size -4M \( -name 'result.json' -o -name '*.csv' -o -name '*.md' -o -name '*.png' -o -name 'config.yaml' \) \
  | tar cf "$OUT/records.tar" -T -)
cp "$WORK"/tables/*.md "$WORK"/tables/*.csv "$OUT/" 2>/dev/null
ls -la "$OUT"
