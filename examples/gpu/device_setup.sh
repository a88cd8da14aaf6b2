# Sourced at the start of a device call (carry [".whl"], made here by examples/gpu/make_whl.sh):
#   source examples/gpu/device_setup.sh || exit 1
# installs .whl's wheels into /tmp/site, puts LPIPS's weights on the path, installs clods-bench (editable, no deps:
# the machines' image has torch and the rest) and builds gsplat's CUDA kernels (71-89 s on the H200s of 2026-11-27;
# torch keeps the build for later calls on the same warm machine; NO_GSPLAT=1 skips it). Prints what it found.
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || return 1
export PYTHONPATH=/tmp/site:$PWD/.whl/lpips_site PYTHONUNBUFFERED=1 TORCH_CUDA_ARCH_LIST=${TORCH_CUDA_ARCH_LIST:-9.0}
export MAX_JOBS=${MAX_JOBS:-$(nproc)}
python3 -m pip install -q --no-deps --no-build-isolation -e . 2>&1 | grep -v -i warning | tail -2
if [ "${NO_GSPLAT:-0}" != 1 ]; then  # NO_GSPLAT=1: work without splatting on the GPU (the video predictors) skips the build
  _t0=$SECONDS
  python3 -c "from gsplat.cuda._backend import _C; assert _C is not None, 'gsplat CUDA extension missing'" || return 1
  echo "device_setup: gsplat kernels ready in $((SECONDS - _t0)) s"
fi
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader
python3 -c "import torch, numpy, clods_bench.benchmark.scoring.lpips_weights as w; print('torch', torch.__version__, 'numpy', numpy.__version__, 'LPIPS weights', w.default_jax_ckpt_path())"
[ "${NO_GSPLAT:-0}" = 1 ] || python3 -c "import gsplat; print('gsplat', gsplat.__version__)"
