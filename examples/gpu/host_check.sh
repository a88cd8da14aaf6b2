#!/usr/bin/env bash
# The GPU machine's own CPU as a second host for deterministic mode: no GPU work, only the x86 CPU beside it, which
# is another model than the development hosts'. Its image has torch 2.11.0 (the pinned version is 2.13.0, too large
# to carry); numpy is carried at the pinned 2.4.6 so that OpenBLAS and numpy's SIMD paths are the pinned ones.
# torch 2.11 and 2.13 give the same bits on every probe fit (their one difference there, `trunc_normal_`'s algorithm,
# is fixed by `clods_bench.truncated_normal`) and on every `ci` row on the Xeon but MMVP's (batch normalisation's
# backward changed in 2.13): any other row that moves here moved with the CPU.
#
#   HOST_CHECK=1 bash examples/gpu/make_whl.sh                                   # here: the wheels, numpy 2.4.6 among them
#   run(carry=[".whl"], timeout_s=590, command="bash examples/gpu/host_check.sh")  # there: about 9 minutes
#
# Stages, each logged to $OUT (default ./host-check): the CPU's model and flags; `clods-bench numerics --probe`
# against tests/benchmark/speed/data/determinism_probe.json; the deterministic-mode tests; then as much of the seed-0
# `ci` plan as LIMIT (seconds from the start, default 540) allows, 16 jobs, checked against results/ci (tables not
# finished in time are not written nor checked; a second call on the same warm machine resumes them).
set -uo pipefail
OUT=${OUT:-host-check}
LIMIT=${LIMIT:-540}
JOBS=${JOBS:-$(nproc)}
WORK=${WORK:-/tmp/host-check}
mkdir -p "$OUT" "$WORK"
if [ "${SETUP:-1}" = 1 ]; then
  NO_GSPLAT=1 source examples/gpu/device_setup.sh > "$OUT/setup.txt" 2>&1 || { cat "$OUT/setup.txt"; exit 1; }
fi
CLI=${CLI:-clods-bench}
PY=${PY:-python3}
{ lscpu | grep -E "^(Model name|Vendor ID|CPU\(s\)|Flags)" | sed -E 's/^(Flags:\s+).*/\1/'
  lscpu | grep -o -w -E "avx2|avx512f|avx512_bf16|avx512_fp16|fma|amx_tile" | sort -u | tr '\n' ' '; echo
  $PY -c "import torch, numpy, numba, sys; print('python', sys.version.split()[0], 'torch', torch.__version__, 'numpy', numpy.__version__, 'numba', numba.__version__)"
} 2>&1 | tee "$OUT/cpu.txt"
$CLI numerics --probe 2>&1 | tee "$OUT/probe.txt"
$PY - "$OUT/probe.txt" <<'EOF' 2>&1 | tee -a "$OUT/probe.txt"
import json, re, sys
want = json.load(open("tests/benchmark/speed/data/determinism_probe.json"))["digests"]
got = dict(re.findall(r"^probe (.+?): ([0-9a-f]{16})", open(sys.argv[1]).read(), re.M))
for family, digest in want.items():
    print(f"{family}: {'same' if got.get(family) == digest else 'OTHER'} ({got.get(family)} here, {digest} committed)")
EOF
$PY -m pytest -q -p no:cacheprovider tests/test_deterministic_mode.py tests/test_exact_math.py tests/test_exact_matmul.py tests/test_fma_gemm.py \
  tests/test_truncated_normal.py 2>&1 | tail -n 15 | tee "$OUT/pytest.txt"
left=$((LIMIT - SECONDS))
echo "ci plan, seed 0: $JOBS jobs, budget $((left - 60)) s (start $SECONDS s)" | tee "$OUT/check.txt"
timeout -k 10 -s INT "$left" $CLI reproduce --preset ci --jobs "$JOBS" --first-seeds 1 --budget $((left - 60)) --no-progress \
  --set runs_dir="$WORK/runs" --set data.root="$WORK/data" --out "$WORK/fresh" --check results/ci >> "$OUT/check.txt" 2>&1
echo "reproduce rc=$? at $SECONDS s" | tee -a "$OUT/check.txt"
tail -n 40 "$OUT/check.txt"
cp "$WORK"/fresh/*.csv "$WORK"/fresh/digests.json "$OUT/" 2>/dev/null
exit 0
