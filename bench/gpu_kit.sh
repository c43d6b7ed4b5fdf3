#!/usr/bin/env bash
# Pack what a CUDA machine without network needs for bench/gpu_check.py into .gpu/ (git-ignored through
# .git/info/exclude, so it travels with a copy of the working tree but is never committed):
#   .gpu/whl/   the wheels that machine's Python 3.12 image lacks (gsplat, OpenImageIO, flip-evaluator); gsplat's
#               wheel holds CUDA sources that it compiles on first use (nvcc is there)
#   .gpu/clip/  one clip without its ground truth (input/ and priors/: ~27 MB at the small preset)
# and print the command to run there. Needs network to PyPI here.
#
#   [OLD=COMMIT] bash bench/gpu_kit.sh CLIP_DIR [PYTHON_VERSION]     e.g. bash bench/gpu_kit.sh ROOT/clips/syn-exp-3/lamp-room-orbit
#   .gpu/old/   with OLD set: that commit's m4dgs/ and bench/, for gpu_session.sh's side-by-side slot D
set -euo pipefail
cd "$(dirname "$0")/.."
clip=${1:?usage: bash bench/gpu_kit.sh CLIP_DIR [PYTHON_VERSION]}
pyver=${2:-3.12}
[ -f "$clip/clip.json" ] || { echo "gpu_kit: $clip has no clip.json (not a clip folder)" >&2; exit 2; }
exclude=$(git rev-parse --git-path info/exclude)
mkdir -p "$(dirname "$exclude")"
grep -qx '/.gpu/' "$exclude" 2>/dev/null || echo '/.gpu/' >> "$exclude"
PY=${PYTHON:-.venv/bin/python}
rm -rf .gpu && mkdir -p .gpu/whl .gpu/clip
plat=(--platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64
      --platform manylinux2014_x86_64 --platform any)
for pkg in gsplat==1.5.3 "OpenImageIO>=2.5" "flip-evaluator>=1.2"; do
  "$PY" -m pip download -q --no-deps --only-binary=:all: --python-version "$pyver" --implementation cp \
    "${plat[@]}" -d .gpu/whl "$pkg"
done
name=$(basename "$clip")
mkdir -p ".gpu/clip/$name"
cp "$clip/clip.json" ".gpu/clip/$name/"
cp -r "$clip/input" "$clip/priors" ".gpu/clip/$name/"
# OLD=COMMIT: that commit's code beside this tree's, for gpu_session.sh's side-by-side slot D
if [ -n "${OLD:-}" ]; then
  mkdir -p .gpu/old
  git archive "$OLD" m4dgs bench | tar -x -C .gpu/old
  git rev-parse --short "$OLD" > .gpu/old/COMMIT
  du -sh .gpu/old
fi
du -sh .gpu/whl .gpu/clip
cat <<EOF

Packed. On the CUDA machine (device run, carry [".gpu"], timeout 600), one command:

set -o pipefail; bash bench/gpu_session.sh 2>&1 | tee \$OUT/log.txt

(its time slots and what each measures: the head of bench/gpu_session.sh; what the GPU sessions measured:
docs/performance.md, "The GPU path": a GPU step is bound by its ~1,900 kernel launches; slot D times a change side by side). The
full-length paper run instead (measured once: 11.0 min of phases on an H100; a session's whole device budget), two
calls, the second at once on the warm machine (it resumes the run; with time left, T_PP > 0 times its FPS and
profiles it):

set -o pipefail; PAPER_RUN=1 STEPS_A=env T_A=100 T_P=465 T_B=0 T_C=0 bash bench/gpu_session.sh 2>&1 | tee \$OUT/log.txt
EOF
