#!/usr/bin/env bash
# Pack what a CUDA machine without network needs to render benchgen clips with Mitsuba's CUDA variant through the
# Ray executor (bench/gpu_render.sh), in two parts that each fit one device call beside the working tree (a call
# carries at most 64 MiB in all, the tree ~12 MB of it). Both go under .gpu/ (git-ignored through .git/info/exclude):
#   .gpu/ra/site.tar.xz   Open Image Denoise (pyoidn: its core library holds the network weights, ~48 MB packed)
#                         and Dr.Jit
#   .gpu/rb/site.tar.xz   Ray, Mitsuba and OpenImageIO, trimmed (below);
#   .gpu/rb/whl/          small wheels that bench/gpu_render.sh installs only where the machine's Python lacks the
#                         module (those of Ray's dependencies that the device image lacks: jsonschema and its
#                         dependencies, cffi)
# The versions are this environment's (what the tests run with), for the device's Python (default 3.12). Needs
# network to PyPI here; ~5 min of one CPU core for the xz packing.
#
#   bash bench/gpu_render_kit.sh [PYTHON_VERSION]
#
# Trimmed, because nothing on the render path loads it: Ray's Java jar, dashboard front-end and libraries (RLlib,
# Tune, Train, Serve, Data, LLM, workflows); Mitsuba's spectral, monochrome and polarized variants, its headers,
# stubs and docs, the spectral upsampling table and the plugins benchgen's scenes never name (volumes, curves,
# ellipsoids, SDF grids, sky models, hair, measured and principled materials, the particle tracer); Open Image
# Denoise's HIP and SYCL devices (the CPU and CUDA ones stay); OpenImageIO's command-line tools.
set -euo pipefail
cd "$(dirname "$0")/.."
pyver=${1:-3.12}
PY=${PYTHON:-.venv/bin/python}
exclude=$(git rev-parse --git-path info/exclude)
mkdir -p "$(dirname "$exclude")"
grep -qx '/.gpu/' "$exclude" 2>/dev/null || echo '/.gpu/' >> "$exclude"
ver() { "$PY" -c "from importlib.metadata import version; print(version('$1'))"; }
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
plat=(--platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64
      --platform manylinux2014_x86_64 --platform any)
get() {  # get DEST PACKAGE==VERSION ...
  local dest=$1; shift
  "$PY" -m pip download -q --no-deps --only-binary=:all: --python-version "$pyver" --implementation cp \
    "${plat[@]}" -d "$dest" "$@" 2>&1 | grep -v "^WARNING: Location" || true
}
get "$work/a" "pyoidn==$(ver pyoidn)" "drjit==$(ver drjit)"
get "$work/b" "ray==$(ver ray)" "mitsuba==$(ver mitsuba)" "OpenImageIO==$(ver OpenImageIO)"
rm -rf .gpu/ra .gpu/rb && mkdir -p .gpu/ra .gpu/rb/whl
# Ray's and benchgen's small dependencies that the device image lacks; msgpack, click, tqdm, PyYAML, protobuf,
# requests (with urllib3, idna, certifi, charset-normalizer), attrs, filelock and packaging are in it, and part b
# with every one of them packed came to more than a call carries
extras=(cffi pycparser jsonschema jsonschema-specifications referencing rpds-py)
get .gpu/rb/whl $(for p in "${extras[@]}"; do echo "$p==$(ver "$p")"; done)
for part in a b; do
  mkdir -p "$work/site-$part"
  for w in "$work/$part"/*.whl; do
    [ -f "$w" ] || { echo "gpu_render_kit: no wheel downloaded for part $part" >&2; exit 1; }
    unzip -q -o "$w" -d "$work/site-$part"  # unzip keeps the executable bits (Ray's gcs_server, raylet)
  done
done
(
  cd "$work/site-a/pyoidn/oidn/lib"
  rm -f ./*hip* ./*sycl* ./libur_* ./libumf*
)
(
  cd "$work/site-b"
  rm -rf ray/jars ray/dashboard/client/build ray/rllib ray/tune ray/train ray/serve ray/data ray/llm ray/workflow \
    ./*.data share OpenImageIO/bin
  rm -rf mitsuba/include mitsuba/mitsuba_stubs mitsuba/data/srgb.coeff
  rm -f mitsuba/*.pyi mitsuba/*spectral* mitsuba/*mono* mitsuba/*polarized*
  cd mitsuba/plugins
  rm -f ellipsoids*.so volpath*.so bsplinecurve.so linearcurve.so sdfgrid.so sunsky.so timed_sunsky.so ptracer.so \
    principled*.so hair.so measured*.so pplastic.so prb*.so polarizer.so retarder.so
)
for part in a b; do
  tar -C "$work/site-$part" -cf - . | xz -6 -T1 > ".gpu/r$part/site.tar.xz"
done
du -sh .gpu/ra .gpu/rb
tree=$(git ls-files -z | xargs -0 du -cb 2>/dev/null | tail -1 | cut -f1)
for part in ra rb; do
  total=$(( tree + $(du -sb ".gpu/$part" | cut -f1) ))
  if [ "$total" -gt $(( 64 * 1024 * 1024 )) ]; then
    echo "gpu_render_kit: .gpu/$part and the tree come to $total bytes, over a device call's 64 MiB" >&2
    exit 1
  fi
done
cat <<EOF

Packed. On the CUDA machine, two device calls, the second at once (the machine keeps /tmp while warm, ~30 s):

  carry [".gpu/ra"], timeout 120:  bash bench/gpu_render.sh a
  carry [".gpu/rb"], timeout 600:  set -o pipefail; bash bench/gpu_render.sh b 2>&1 | tee \$OUT/log.txt

(what stage b renders and measures, and its time limit: the head of bench/gpu_render.sh)
EOF
