#!/usr/bin/env bash
# Device call (session 35). MODE=first: install, generate the small datasets (10-camera and the 30-camera Table 3 rig),
# then, side by side on the GPU: A = Table 4's predictor rows at small (seed 0; copy last, TAU, MMVP, SimVP on cuda,
# 4 workers), B = Table 3's per-frame 3DGS row at small (gsplat on cuda). MODE=resume: resume what did not finish.
# Brings back the tables, the run records and the logs. carry [".whl"]; command: MODE=first LIMIT=570 bash .whl/drive4.sh
D=$OUT; unset OUT
LIMIT=${LIMIT:-570}; MODE=${MODE:-first}
exec > >(tee -a "$D/driver.log") 2>&1
echo "start $(date +%T) mode=$MODE"
if [ "$MODE" = first ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
  mkdir -p /tmp/gsplat_so && tar xJf .whl/gsplat_cuda_so.tar.xz -C /tmp/gsplat_so
fi
export GSPLAT_PREBUILT=/tmp/gsplat_so/gsplat_cuda.so PYTHONPATH=/tmp/site:$PWD/.whl/site_hook:$PWD/.whl/lpips_site PYTHONUNBUFFERED=1
python3 -m pip install -q --no-deps --no-build-isolation -e . 2>&1 | grep -v -i warning | tail -2
export TORCH_CUDA_ARCH_LIST=9.0 MAX_JOBS=16
if [ "$MODE" = first ]; then
  nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv; nproc
  python3 -c "import torch, numpy; print('torch', torch.__version__, torch.version.cuda, 'numpy', numpy.__version__)"
  (t0=$SECONDS; python3 -c "from gsplat.cuda._backend import _C; print('gsplat _C:', _C.__name__)" 2>&1 | tail -1; echo "gsplat import $((SECONDS - t0)) s") > /tmp/gsplat_import.log 2>&1 &
  GS=$!
  t0=$SECONDS
  clods-bench data generate --scene flag --preset small --jobs 8 --no-progress > "$D/datagen10.log" 2>&1 &
  G1=$!
  clods-bench data generate --scene flag --preset small --set data.num_cameras=30 --set data.num_views_test=5 --jobs 8 --no-progress > "$D/datagen30.log" 2>&1 &
  G2=$!
  wait $G1; echo "datagen 10 cameras rc=$? $((SECONDS - t0)) s"; tail -3 "$D/datagen10.log"
fi
SA="--set video_config.tau.device=cuda --set video_config.mmvp.device=cuda --set video_config.simvp.device=cuda"
left=$((LIMIT - SECONDS - 25))
echo "A (table 4) with timeout ${left} s at $SECONDS s"
timeout -s INT "$left" clods-bench reproduce --preset small --plan .whl/table4_plan_small.yaml --first-seeds 1 --jobs 4 \
  $SA --set runs_dir=/tmp/r4 --out /tmp/o4 --no-progress > "$D/table4_$MODE.log" 2>&1 &
A=$!
if [ "$MODE" = first ]; then
  wait $G2; echo "datagen 30 cameras rc=$? $((SECONDS - t0)) s"; tail -3 "$D/datagen30.log"
  wait $GS; cat /tmp/gsplat_import.log
fi
if [ ! -f /tmp/o3/table3_nvs.csv ]; then
  left=$((LIMIT - SECONDS - 25))
  echo "B (table 3 3DGS) with timeout ${left} s at $SECONDS s"
  timeout -s INT "$left" clods-bench reproduce --preset small --plan .whl/table3_gs3d_plan_small.yaml --first-seeds 1 \
    --set renderer_config.gs3d.backend=gsplat --set renderer_config.gs3d.device=cuda \
    --set runs_dir=/tmp/r3 --out /tmp/o3 --no-progress > "$D/table3_$MODE.log" 2>&1
  echo "B rc=$? at $SECONDS s"; tail -8 "$D/table3_$MODE.log"
fi
nvidia-smi --query-gpu=utilization.gpu,memory.used --format=csv
wait $A; echo "A rc=$? at $SECONDS s"; tail -12 "$D/table4_$MODE.log"
for r in 3 4; do
  mkdir -p "$D/o$r" "$D/t$r"
  cp /tmp/o$r/* "$D/o$r/" 2>/dev/null
  clods-bench tables --runs /tmp/r$r --out "$D/t$r" > /dev/null 2>&1 || echo "tables r$r rc=$?"
  (cd /tmp && find r$r -type f -size -3M \( -name '*.json' -o -name '*.csv' -o -name '*.png' -o -name '*.mp4' -o -name '*.txt' -o -name '*.yaml' \) | tar cf - -T - | tar xf - -C "$D/")
done
du -sh "$D"
echo "end $SECONDS s"
