#!/usr/bin/env bash
# Device call (session 34). MODE=first: install, build gsplat, ship the built .so back, full paper trajectory (JOBS=3),
# then bench video small on cuda if time is left. MODE=resume (same warm machine): resume the trajectory from its
# caches, then bench video small on cuda.
D=$OUT; unset OUT
LIMIT=${LIMIT:-585}
MODE=${MODE:-first}
exec > >(tee -a "$D/driver.log") 2>&1
echo "start $(date +%T) mode=$MODE"
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site
python3 -m pip install -q --no-deps --no-build-isolation -e . 2>&1 | grep -v -i warning | tail -2
export TORCH_CUDA_ARCH_LIST=9.0 MAX_JOBS=16 PYTHONUNBUFFERED=1
t0=$SECONDS; python3 -c "from gsplat.cuda._backend import _C" 2>&1 | tail -1; echo "gsplat import/build $((SECONDS - t0)) s"
if [ "$MODE" = first ]; then
  nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv; nproc
  python3 -c "import torch; print(torch.__version__, torch.version.cuda)"
  b=$(python3 -c "from torch.utils.cpp_extension import _get_build_directory as g; print(g('gsplat_cuda', False))")
  ls -la "$b"/*.so; (cd "$b" && tar cf - gsplat_cuda.so | xz -T16 -3 > "$D/gsplat_cuda_so.tar.xz"); ls -la "$D"
fi
if [ ! -f /tmp/pt/done ]; then
  left=$((LIMIT - SECONDS - 15))
  echo "paper_trajectory.sh with timeout ${left} s at $SECONDS s"
  OUT=/tmp/pt JOBS=3 timeout "$left" bash examples/gpu/paper_trajectory.sh > "$D/paper_trajectory_$MODE.log" 2>&1
  rc=$?; echo "paper_trajectory.sh rc=$rc at $SECONDS s"; [ $rc = 0 ] && touch /tmp/pt/done
  tail -12 "$D/paper_trajectory_$MODE.log"
  cp /tmp/pt/stages.txt "$D/stages_$MODE.txt" 2>/dev/null; cp /tmp/pt/log.txt "$D/log_$MODE.txt" 2>/dev/null
  mkdir -p "$D/runs" && (cd /tmp/pt/runs && find . -name 'result.json' | head -1 | xargs -r -I{} cp {} "$D/runs/")
fi
left=$((LIMIT - SECONDS - 5))
if [ "$left" -gt 40 ]; then
  echo "bench video small cuda with timeout ${left} s at $SECONDS s"
  timeout "$left" clods-bench bench video --preset small --device cuda --no-cpu 2>&1 | tee "$D/bench_video_small_cuda.txt"
  echo "bench video rc=$? at $SECONDS s"
fi
echo "end $SECONDS s"
