#!/usr/bin/env bash
# Device call (written session 38; drive6 plus the extraction cache brought back): the paper trajectory again, with the paper preset's new stage-2
# settings (learning_rate 0.01, stop_requires_progress), to compare its E-GT curve with the fifth visit's (defaults:
# lost the cloth after frame 222). Prebuilt gsplat .so, one call; a timeout leaves the partial extraction, whose
# E-GT curve stage2_progress.py prints from the cache.   carry [".whl"]; command: LIMIT=580 bash .whl/drive6.sh
D=$OUT; unset OUT
LIMIT=${LIMIT:-580}
exec > >(tee -a "$D/driver.log") 2>&1
echo "start $(date +%T)"
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
mkdir -p /tmp/gsplat_so && tar xJf .whl/gsplat_cuda_so.tar.xz -C /tmp/gsplat_so
export GSPLAT_PREBUILT=/tmp/gsplat_so/gsplat_cuda.so PYTHONPATH=/tmp/site:$PWD/.whl/site_hook:$PWD/.whl/lpips_site PYTHONUNBUFFERED=1
python3 -m pip install -q --no-deps --no-build-isolation -e . 2>&1 | grep -v -i warning | tail -2
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv; nproc
left=$((LIMIT - SECONDS - 40))
echo "paper_trajectory.sh with timeout ${left} s at $SECONDS s"
OUT=/tmp/pt JOBS=3 STAGE3_STEPS=20 timeout -k 10 -s INT "$left" bash examples/gpu/paper_trajectory.sh > "$D/paper_trajectory.log" 2>&1
echo "rc=$? at $SECONDS s"
python3 examples/gpu/stage2_progress.py /tmp/pt/runs --data "$(ls -d /tmp/pt/data/flag-* | head -1)" --every 10 > "$D/egt_curve.txt" 2>&1
cat "$D/egt_curve.txt"
cp /tmp/pt/stages.txt /tmp/pt/log.txt "$D/" 2>/dev/null
(cd /tmp/pt && find runs -type f \( -name "traj_*.npz" -o -name "result.json" -o -name "*.md" \) -size -20M | tar cf "$D/pt_records.tar" -T -)
nvidia-smi --query-gpu=name,memory.used --format=csv
echo "end $SECONDS s"
