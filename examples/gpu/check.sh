#!/usr/bin/env bash
# The GPU path of the current code, checked on one CUDA machine in under 10 minutes (docs/gpu.md, "Checking a GPU
# machine"), one step after the other, each under a time budget:
#   env        what the machine is: GPU, driver, torch and CUDA, gsplat, clods-bench and its commit (env.json)
#   gsplat     gsplat's CUDA kernels loaded (built on first use: 60-90 s)
#   agreement  the CPU-against-GPU tests of every backend (splatting, 2DGS surfels, the renderers' fits, stage 0, the
#              learned simulators, the video predictors), within the tolerances each states; and the --device tests
#   switch     `clods-bench run nvs --renderer smgs --preset ci --device cuda`, one seed: the switch end to end
#   fit        examples/gpu/paper_size_fit.py: GaMeS and SMGS fit and stage-2 step at 25 views of 800 px, CPU and GPU
#   infer      `clods-bench bench infer --device cuda --preset paper`: CloDS per frame against the traditional pipeline
#   sim        `clods-bench bench sim --device cuda`: MGN's training and rollout step at 1579 nodes, CPU and GPU
# Every log, the tests' JUnit XML, the run's record and summary.md / summary.json go to
# results/gpu/<gpu>-<YYYY-MM-DD>/ (the GPU's name from nvidia-smi, else torch). Exit 0 when the GPU path is confirmed
# (every agreement test ran and passed, the device reached the run, every step finished), else 1; 2 when it cannot start.
#
#   bash examples/gpu/check.sh                                # a CUDA build of torch, gsplat and clods-bench installed
#   source examples/gpu/device_setup.sh && BUDGET_TOTAL=$((570 - SECONDS)) bash examples/gpu/check.sh
#                                                             # no network there: the wheels of examples/gpu/make_whl.sh
#   DEVICE=cpu RESULTS=/tmp/gpu-check bash examples/gpu/check.sh   # the same steps on the CPU at a tiny size (the
#                                                             # agreement tests skip): the script's own check
# Environment: DEVICE (cuda), RESULTS (the folder above), BUDGET_TOTAL (seconds for all steps: 480, 1800 with
# DEVICE=cpu; a step gets at most what is left), BUDGET_ENV, BUDGET_GSPLAT, BUDGET_AGREEMENT, BUDGET_SWITCH,
# BUDGET_FIT, BUDGET_INFER, BUDGET_SIM (each step's own), PYTHON (python3), CLODS_BENCH (clods-bench), WORK (the
# scratch folder of the run's data; default a fresh temporary one, removed at the end).
set -uo pipefail
cd "$(dirname "$0")/../.." || exit 2
DEVICE=${DEVICE:-cuda}
PYTHON=${PYTHON:-python3}
CLODS_BENCH=${CLODS_BENCH:-clods-bench}
export PYTHONUNBUFFERED=1 COLUMNS=${COLUMNS:-160} MAX_JOBS=${MAX_JOBS:-$(nproc)}  # rich's tables this wide in the logs; gsplat's build on every core
SUMMARY="examples/gpu/check_summary.py"
if [ -z "${RESULTS:-}" ]; then
  RESULTS=$($PYTHON "$SUMMARY" folder --device "$DEVICE") || exit 2
fi
mkdir -p "$RESULTS" || exit 2
if [ -z "${WORK:-}" ]; then
  WORK=$(mktemp -d "${TMPDIR:-/tmp}/clods-gpu-check.XXXXXX") || exit 2
  trap 'rm -rf "$WORK"' EXIT
fi
mapfile -t AGREEMENT < <($PYTHON "$SUMMARY" tests)
[ "${#AGREEMENT[@]}" -gt 0 ] || { echo "check.sh: no agreement tests listed by $SUMMARY" >&2; exit 2; }

if [ "$DEVICE" = cpu ]; then  # the stand-in: the same steps, sizes cut to what 2 CPU cores do in minutes
  TOTAL=${BUDGET_TOTAL:-1800}
  TINY=(--set "data.resolution=[6,4]" --set data.num_train=2 --set data.num_test=1 --set data.num_steps=12 --set data.interp_steps=8
        --set data.num_cameras=3 --set data.num_views_test=1 --set data.image_size=24 --set task_config.nvs.num_trajectories=5
        --set task_config.nvs.frame_stride=1 --set renderer_config.smgs.iterations=20)
  FIT_ARGS=(--setups cpu --size 48 --views 2 --iterations 1)
  INFER_ARGS=(--preset ci --frames 1)
  SIM_ARGS=(--sims mgn physics --frames 4 --set sim_config.mgn.latent_size=16 --set sim_config.mgn.message_passing_steps=2)
  SLOW=4  # every budget times this: the same steps take longer on 2 cores
else
  TOTAL=${BUDGET_TOTAL:-480}
  TINY=()
  FIT_ARGS=(--size 800 --views 25 --iterations 3)
  INFER_ARGS=(--preset paper --frames 3)
  SIM_ARGS=(--sims mgn physics --frames 12 --set sim_config.mgn.loss=rollout)
  SLOW=1
fi

START=$SECONDS
: > "$RESULTS/steps.tsv"
echo "GPU check, DEVICE=$DEVICE: logs and summary in $RESULTS (at most $TOTAL s)"

# step NAME BUDGET COMMAND...: COMMAND under min(BUDGET, what is left) seconds, its output in NAME.log; one line of
# steps.tsv (name, budget, seconds, exit status) whatever happens.
step() {
  local name=$1 budget=$(($2 * SLOW)) left t0 rc
  shift 2
  left=$((TOTAL - (SECONDS - START)))
  [ "$budget" -gt "$left" ] && budget=$left
  if [ "$budget" -lt 10 ]; then
    printf '%s\t%s\t0\tskip:the time budget is spent\n' "$name" "$budget" >> "$RESULTS/steps.tsv"
    echo "== $name: not run, the time budget is spent"
    return 0
  fi
  echo "== $name (at most $budget s): $*"
  t0=$SECONDS
  timeout -s INT -k 15 "$budget" "$@" > "$RESULTS/$name.log" 2>&1
  rc=$?
  printf '%s\t%s\t%s\t%s\n' "$name" "$budget" "$((SECONDS - t0))" "$rc" >> "$RESULTS/steps.tsv"
  echo "   exit $rc after $((SECONDS - t0)) s"
  tail -n 3 "$RESULTS/$name.log" | sed 's/^/   | /'
}

skip() {  # skip NAME WHY: a step this device has no use for
  printf '%s\t0\t0\tskip:%s\n' "$1" "$2" >> "$RESULTS/steps.tsv"
  echo "== $1: not run ($2)"
}

step env "${BUDGET_ENV:-60}" $PYTHON "$SUMMARY" env --device "$DEVICE" --out "$RESULTS/env.json"
if [ "$DEVICE" = cpu ]; then
  skip gsplat "DEVICE=cpu"
else
  step gsplat "${BUDGET_GSPLAT:-150}" $PYTHON -c "from gsplat.cuda._backend import _C; assert _C is not None, 'gsplat CUDA extension missing'"
fi
step agreement "${BUDGET_AGREEMENT:-200}" $PYTHON -m pytest -q -rs -m "slow or not slow" -p no:cacheprovider \
  --junitxml="$RESULTS/agreement.xml" "${AGREEMENT[@]}" tests/benchmark/core/test_device_switch.py tests/cli/test_device_cli.py
step switch "${BUDGET_SWITCH:-120}" $CLODS_BENCH run nvs --renderer smgs --preset ci --device "$DEVICE" --seeds 0 --jobs 1 --no-progress \
  --set runs_dir="$RESULTS/runs" --set data.root="$WORK/data" ${TINY[@]+"${TINY[@]}"}
step fit "${BUDGET_FIT:-90}" $PYTHON examples/gpu/paper_size_fit.py "${FIT_ARGS[@]}" --json "$RESULTS/paper_size_fit.json"
step infer "${BUDGET_INFER:-75}" $CLODS_BENCH bench infer --device "$DEVICE" "${INFER_ARGS[@]}" --out "$RESULTS/infer" --no-progress
step sim "${BUDGET_SIM:-75}" $CLODS_BENCH bench sim --device "$DEVICE" "${SIM_ARGS[@]}"

echo "== summary ($((SECONDS - START)) s in all)"
$PYTHON "$SUMMARY" summarize "$RESULTS"
rc=$?
echo "   $RESULTS/summary.md"
exit "$rc"
