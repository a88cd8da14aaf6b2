#!/usr/bin/env bash
# Device call 2: install, build gsplat, a shortened paper trajectory (STEPS frames, all stages), then bench infer paper.
D=$OUT; unset OUT
LIMIT=${LIMIT:-255}
exec > >(tee -a "$D/driver.log") 2>&1
echo "start $(date +%T)"
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site
python3 -m pip install -q --no-deps --no-build-isolation -e . 2>&1 | grep -v -i warning | tail -2
export TORCH_CUDA_ARCH_LIST=9.0 MAX_JOBS=16
t0=$SECONDS; python3 -c "from gsplat.cuda._backend import _C" 2>&1 | tail -1; echo "gsplat build $((SECONDS - t0)) s"
left=$((LIMIT - SECONDS - 45))
echo "paper_trajectory.sh STEPS=${STEPS} with timeout ${left} s at $SECONDS s"
OUT=/tmp/pt JOBS=3 STEPS=$STEPS STAGE3_STEPS=${STAGE3_STEPS:-50} timeout "$left" bash examples/gpu/paper_trajectory.sh > "$D/paper_trajectory.log" 2>&1
echo "paper_trajectory.sh rc=$? at $SECONDS s"
tail -8 "$D/paper_trajectory.log"
cp /tmp/pt/stages.txt /tmp/pt/log.txt "$D/" 2>/dev/null
mkdir -p "$D/runs" && (cd /tmp/pt/runs && find . -name 'result.json' -o -name 'record.json' -o -name '*train_log.json' | xargs -r cp --parents -t "$D/runs/")
left=$((LIMIT - SECONDS - 3))
if [ "$left" -gt 35 ]; then
  echo "bench infer paper with timeout ${left} s at $SECONDS s"
  timeout "$left" clods-bench bench infer --device cuda --preset paper --frames 3 --out "$D/infer" --no-progress
  echo "bench infer rc=$?"
fi
echo "end $SECONDS s"
