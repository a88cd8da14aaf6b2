#!/usr/bin/env bash
# One paper-size trajectory through data generation and CloDS stages 1-3, each stage timed.
#
# PRESET (default paper) sets the sizes: FLAGSIMPLE-sized flag, 401 frames, 30 cameras (25 fitted), 800 px. Two
# training trajectories (the fewest a split allows) and one test trajectory, frames rendered on demand
# (data.frames=on_demand: meshes + render setup on disk), the CloDS* row (`run cdg --sim mgn --renderer smgs
# --train-subset first_half`: the videos of training trajectory 0 only) with SMGS on BACKEND/DEVICE (default gsplat/cuda) and MGN's
# stage-3 training cut to STAGE3_STEPS steps, all of them with the paper's 8-step rollout loss (its per-step time is
# what the estimate needs), MGN on SIM_DEVICE (default DEVICE). STEPS (optional) cuts the trajectories to that many frames; EXTRA
# (optional) adds `--set` options to the CloDS* run (e.g. fewer fit iterations for a smoke test on a CPU).
#
#   bash examples/gpu/paper_trajectory.sh                                   # on a GPU machine
#   PRESET=ci BACKEND=cpu DEVICE=cpu bash examples/gpu/paper_trajectory.sh  # the same steps, small, on a CPU
#
# Prints each command's wall time, the files the run writes as it goes (stage boundaries, also in $OUT/stages.txt),
# then the stage timings of the run record (stage 1 fit, stage 2 per frame, stage 3 per training step) and the
# bytes on disk.
set -euo pipefail
PRESET=${PRESET:-paper}
OUT=${OUT:-paper-trajectory}
BACKEND=${BACKEND:-gsplat}
DEVICE=${DEVICE:-cuda}
SIM_DEVICE=${SIM_DEVICE:-$DEVICE}
STAGE3_STEPS=${STAGE3_STEPS:-100}
common=(--preset "$PRESET" --no-progress --set data.num_train=2 --set data.num_test=1 --set data.frames=on_demand
        --set data.root="$OUT/data")
if [ -n "${STEPS:-}" ]; then
  common+=(--set data.num_steps="$STEPS" --set data.interp_steps=$((STEPS * 3 / 4)))
fi
mkdir -p "$OUT"
/usr/bin/time -f "data generate: %e s wall" clods-bench data generate "${common[@]}" --jobs "${JOBS:-2}" 2>&1 | tee -a "$OUT/log.txt"
# Stage boundaries as they happen (the run prints its timings only at the end): every file the run writes, with the
# seconds since the run began: the stage-1 fit (clods_cache/stage1-*.pt), stage 2's per-frame partial saves,
# stage 3's checkpoints, result.json.
mkdir -p "$OUT/runs" && touch "$OUT/.mark" && began=$SECONDS
# (`|| true`: under `set -e` a quiet poll, where grep matches nothing, would end the watcher.) `$!` must be the loop
# itself, not a `| tee` after it: killing tee alone left the loop holding this script's stdout open, so a caller
# piping the script's output waited forever after the script ended.
watch_files() {
  while sleep 2; do { find "$OUT/runs" -type f -newer "$OUT/.mark" -printf "%P %s\n" 2>/dev/null | grep -v '\.lock' |
    sed "s/^/[$((SECONDS - began)) s] wrote /"; } || true; touch "$OUT/.mark"; done
}
watch_files > >(tee -a "$OUT/stages.txt") &
watcher=$!
# On exit, finished or stopped by a time limit: how far stage 2 got, from its per-frame partial saves, and its E-GT
# curve against the dataset's true meshes.
here=$(cd "$(dirname "$0")" && pwd)
trap 'kill $watcher 2>/dev/null || true; ds=$(ls -d "$OUT"/data/*/ 2>/dev/null | head -1)
      python3 "$here/stage2_progress.py" "$OUT/runs" ${ds:+--data "$ds"} 2>&1 | tee -a "$OUT/log.txt"' EXIT
/usr/bin/time -f "run cdg, CloDS* (stages 1-3, rollouts, scoring): %e s wall" clods-bench run cdg --sim mgn --renderer smgs \
  --train-subset first_half "${common[@]}" --set seeds=[0] --set runs_dir="$OUT/runs" --label "CloDS* (one paper-size trajectory)" \
  --set renderer_config.smgs.backend="$BACKEND" --set renderer_config.smgs.device="$DEVICE" --set sim_config.mgn.device="$SIM_DEVICE" \
  --set task_config.clods.sim_overrides.loss=rollout --set task_config.clods.sim_overrides.rollout_length=8 \
  --set task_config.clods.sim_overrides.train_steps="$STAGE3_STEPS" \
  --set task_config.clods.sim_overrides.warmup_steps=$((STAGE3_STEPS / 5)) --set task_config.clods.sim_overrides.rollout_start_step=0 \
  ${EXTRA:-} 2>&1 | tee -a "$OUT/log.txt"
python3 - "$OUT" $((STAGE3_STEPS / 5)) <<'EOF' 2>&1 | tee -a "$OUT/log.txt"
import json, pathlib, sys
out, warmup = pathlib.Path(sys.argv[1]), int(sys.argv[2])
res = json.loads(next(out.glob("runs/cdg/**/seed_0/result.json")).read_text())
t = res["timings"]
steps = t.get("fit/stage3/train_steps", 0)
print(f"stage 1 (renderer fit on frame 0): {t['fit/stage1_cost_seconds']:.1f} s")
print(f"stage 2 (mesh extraction): {t['fit/stage2_ms_per_frame']:.1f} ms per frame, {t['fit/stage2_iterations_per_frame']:.1f} "
      f"iterations per frame, {t['fit/stage2_frames']:.0f} frames; {t.get('fit/stage2_wall_seconds', float('nan')):.1f} s wall, reading the "
      f"frames (rendered on demand) included")
print(f"stage 3 (MGN on the extracted meshes, 8-step rollout loss): {t['fit/stage3/train_seconds']:.1f} s for "
      f"{steps:.0f} steps = {1000 * t['fit/stage3/train_seconds'] / max(steps - warmup, 1):.1f} ms per optimiser step "
      f"(the {warmup} warm-up steps only feed the normalisers)")
print(f"rollout: {t['infer_ms_per_step']:.2f} ms per step")
size = lambda p: sum(f.stat().st_size for f in p.rglob("*") if f.is_file())
print(f"disk: data {size(out / 'data') / 1e6:.1f} MB, runs {size(out / 'runs') / 1e6:.1f} MB")
EOF
