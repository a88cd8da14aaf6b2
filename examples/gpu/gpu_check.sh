#!/usr/bin/env bash
# The checks only a CUDA machine can do, in stages (default: all): `bash examples/gpu/gpu_check.sh [build] [test] [bench] [fit] [nvs] [surfels] [sims] [infer]`.
#   build: compile gsplat's CUDA kernels (JIT, first use) and time it
#   test:  the splatting and renderer tests, the gsplat-vs-cpu agreement tests among them (-rs lists skips)
#   bench: `clods-bench bench render` with the gsplat column at the issue's size (8 views, 128 px, with the
#          torch reference) and at the paper's image size (30 views, 800 px, cpu vs gsplat)
#   fit:   examples/gpu/paper_size_fit.py: GaMeS / SMGS fit and stage-2 step at 25 views of 800 px, cpu vs GPU
#   nvs:   `clods-bench run nvs --preset ci` for smgs on the GPU (device cuda, backend gsplat) and on the CPU
#   surfels: the 2DGS surfel backend: gsplat's 2DGS kernels against the cpu backend, stage 0 of a bent flag on both
#          (examples/gpu/surfel_nan.py traces its NaN on gsplat), and `clods-bench run initial_mesh --preset ci` (seed 0) with the surfel fit on gsplat and on the CPU
#   sims:  the learned simulators and video predictors on CUDA against the CPU, then MGN's `small` training speed on both
#          (data.frames=on_demand: the stability task reads meshes only), and `bench sim --device cuda` (CPU vs GPU in one run)
#   infer: `clods-bench bench infer --device cuda` at `ci` and `paper` (CloDS: MGN step + SMGS on gsplat, against the
#          physics solver + rasterizer on the CPU; the inference-time figure's GPU numbers)
# Logs go to $OUT (default ./gpu-check). Needs: clods-bench installed, gsplat, torch with CUDA, nvcc.
set -uo pipefail
OUT=${OUT:-gpu-check}
mkdir -p "$OUT"
export PYTHONUNBUFFERED=1 MAX_JOBS=${MAX_JOBS:-$(nproc)}
stages=${*:-build test bench fit nvs surfels sims infer}
log() { tee -a "$OUT/$1"; }
for stage in $stages; do
  case $stage in
    build)
      nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv 2>&1 | log gpu.txt
      python3 -c "import torch, gsplat; print('torch', torch.__version__, 'cuda', torch.version.cuda, 'gsplat', gsplat.__version__, torch.cuda.get_device_name())" 2>&1 | log gpu.txt
      /usr/bin/time -f "gsplat kernels built/loaded in %e s" python3 -c "from gsplat.cuda._backend import _C; assert _C is not None, 'gsplat extension missing'" 2>&1 | log gpu.txt ;;
    test)
      python3 -m pytest -q -rs tests/splatting tests/plugins/renderers 2>&1 | log pytest_gpu.txt ;;
    bench)
      clods-bench bench render 2>&1 | log bench_render.txt
      clods-bench bench render --views 30 --size 800 --no-reference 2>&1 | log bench_render.txt ;;
    fit)
      python3 examples/gpu/paper_size_fit.py --size 800 --views 25 --iterations ${FIT_ITERATIONS:-5} 2>&1 | log paper_size_fit.txt ;;
    nvs)
      for setup in cuda:gsplat cpu:cpu; do
        device=${setup%:*} backend=${setup#*:}
        /usr/bin/time -f "run nvs smgs device=$device backend=$backend: %e s" clods-bench run nvs --renderer smgs --preset ci \
          --no-progress --set runs_dir="/tmp/gpu-check-runs-$device" --set renderer_config.smgs.backend=$backend \
          --set renderer_config.smgs.device=$device 2>&1 | log nvs.txt
      done ;;
    surfels)
      python3 -m pytest -q -rs -m "slow or not slow" tests/splatting/test_surfel_gsplat.py tests/benchmark/clods/test_stage0.py 2>&1 | log surfels.txt
      timeout 120 python3 examples/gpu/surfel_nan.py 2>&1 | log surfels.txt  # stage 0 on gsplat: attached RMSE, non-finite gradients
      for backend in gsplat cpu; do
        /usr/bin/time -f "run initial_mesh backend=$backend: %e s" clods-bench run initial_mesh --preset ci --no-progress \
          --set seeds=[0] --set runs_dir="/tmp/gpu-check-runs-s0-$backend" --set task_config.initial_mesh.backend=$backend 2>&1 | log surfels.txt
      done ;;
    sims)
      python3 -m pytest -q -rs tests/plugins/simulators/test_mgn.py tests/plugins/video/test_trainer.py -k "gpu or device" 2>&1 | log sims.txt
      for device in cuda cpu; do
        /usr/bin/time -f "run stability mgn small, 500 steps, device=$device: %e s" clods-bench run stability --sim mgn --preset small \
          --no-progress --set seeds=[0] --set runs_dir="/tmp/gpu-check-runs-sim-$device" --set data.frames=on_demand --set sim_config.mgn.train_steps=500 \
          --set sim_config.mgn.warmup_steps=100 --set sim_config.mgn.device=$device 2>&1 | grep -E "train_seconds|rmse|max_strain|wall|s$" | log sims.txt
      done
      clods-bench bench sim --sims mgn bsms physics --device cuda --frames 12 --set sim_config.mgn.loss=rollout \
        --set sim_config.bsms.loss=rollout 2>&1 | log sims.txt ;;
    infer)
      clods-bench bench infer --device cuda --preset ci --frames 10 --out "$OUT/infer" 2>&1 | log infer.txt
      clods-bench bench infer --device cuda --preset paper --frames 3 --out "$OUT/infer" 2>&1 | log infer.txt ;;
    *) echo "unknown stage '$stage' (known: build test bench fit nvs surfels sims infer)" >&2; exit 2 ;;
  esac
done
