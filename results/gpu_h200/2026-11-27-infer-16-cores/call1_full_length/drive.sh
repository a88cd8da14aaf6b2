#!/usr/bin/env bash
# Device call: install, build gsplat, full paper trajectory (timed), then bench infer paper on cuda with what time is left.
D=$OUT; unset OUT
LIMIT=${LIMIT:-590}
exec > >(tee -a "$D/driver.log") 2>&1
echo "start $(date +%T)"
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site
python3 -m pip install -q --no-deps --no-build-isolation -e . 2>&1 | grep -v -i warning | tail -2
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv; nproc; python3 -c "import torch, numba; print(torch.__version__, numba.__version__, numba.config.THREADING_LAYER)"
export TORCH_CUDA_ARCH_LIST=9.0 MAX_JOBS=16
if [ "${STAGE:-all}" = all ] || [ "${STAGE}" = traj ]; then
  t0=$SECONDS; python3 -c "from gsplat.cuda._backend import _C" 2>&1 | tail -1; echo "gsplat build $((SECONDS - t0)) s"
  left=$((LIMIT - SECONDS - 25))
  echo "paper_trajectory.sh with timeout ${left} s at $(date +%T)"
  OUT=/tmp/pt JOBS=3 timeout "$left" bash examples/gpu/paper_trajectory.sh > "$D/paper_trajectory.log" 2>&1
  echo "paper_trajectory.sh rc=$? at $SECONDS s"
  cp /tmp/pt/stages.txt /tmp/pt/log.txt "$D/" 2>/dev/null
  mkdir -p "$D/runs" && (cd /tmp/pt/runs && find . -name 'result.json' -o -name 'record.json' -o -name '*train_log.json' | xargs -r cp --parents -t "$D/runs/")
  du -sh /tmp/pt/data /tmp/pt/runs
fi
left=$((LIMIT - SECONDS - 10))
if [ "$left" -gt 60 ]; then
  python3 -c "from gsplat.cuda._backend import _C" 2>&1 | tail -1
  echo "bench infer paper with timeout ${left} s"
  timeout "$left" clods-bench bench infer --device cuda --preset paper --frames 5 --out "$D/infer" --no-progress
  echo "bench infer rc=$?"
fi
echo "end $SECONDS s"
