#!/usr/bin/env bash
# Device call (session 38, second): the GPU-agreement tests after sessions 36-37's changes (stage 2, codecs), in the
# files that hold CUDA cases, 8 xdist workers; -v names each result as it comes (the session-38 try ran -q: 1 failure
# among ~200 results, unnamed, when the 231-s limit stopped it), --timeout ends a hung test.   carry [".whl"]; command: LIMIT=250 bash .whl/drive8.sh
D=$OUT; unset OUT
LIMIT=${LIMIT:-250}
exec > >(tee -a "$D/driver.log") 2>&1
echo "start $(date +%T)"
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
mkdir -p /tmp/gsplat_so && tar xJf .whl/gsplat_cuda_so.tar.xz -C /tmp/gsplat_so
export GSPLAT_PREBUILT=/tmp/gsplat_so/gsplat_cuda.so PYTHONPATH=/tmp/site:$PWD/.whl/site_hook:$PWD/.whl/lpips_site PYTHONUNBUFFERED=1
python3 -m pip install -q --no-deps --no-build-isolation -e . 2>&1 | grep -v -i warning | tail -2
left=$((LIMIT - SECONDS - 15))
echo "pytest with timeout ${left} s at $SECONDS s"
timeout -k 5 -s INT "$left" python3 -m pytest -v -rfs -n 8 --timeout 120 -p no:cacheprovider -p no:benchmark tests/benchmark/clods/test_extract.py \
  tests/benchmark/test_fit_cache.py tests/benchmark/test_sim_bench.py tests/benchmark/test_infer_bench.py \
  tests/plugins/simulators/test_mgn.py tests/plugins/video/test_trainer.py tests/plugins/splatting \
  tests/plugins/renderers/test_device.py > "$D/pytest_gpu.txt" 2>&1
echo "rc=$? at $SECONDS s"
tail -40 "$D/pytest_gpu.txt"
echo "end $SECONDS s"
