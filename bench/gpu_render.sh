#!/usr/bin/env bash
# Render one benchgen clip at the paper preset with Mitsuba's CUDA variant through the Ray executor (one GPU per
# render task) on a CUDA machine without network, from the kit that `bash bench/gpu_render_kit.sh` packed here, and
# record its seconds per frame. Two device calls, the second at once so that the machine is still warm:
#
#   bash bench/gpu_render.sh a                                       (carry [".gpu/ra"]) unpack part a into $GR/site
#   set -o pipefail; bash bench/gpu_render.sh b 2>&1 | tee $OUT/log.txt   (carry [".gpu/rb"]) the rest, then render
#
# Stage b unpacks part b, installs the kit's small wheels whose module this Python lacks, checks that Mitsuba's CUDA
# variant loads, then runs
#   BENCHGEN_MI_VARIANT=cuda_ad_rgb python3 -m benchgen make --exposures 3 --scenes $SCENE --preset $PRESET \
#       --executor $EXECUTOR --cpus-per-job $CPUS --render-only --out $GR/bench
# cut at T_RENDER seconds (every finished frame stays on disk, so stage b again continues where it stopped). If the
# Ray run renders nothing and its log says Ray failed to start, it renders once more with the local executor and
# says so. Last, $OUT/render.json: the render seconds of every frame rendered (each frame's stats file), the views'
# task seconds per test frame, how many frames and views are on disk, the executor used; $OUT/gpu.txt and env.txt
# the GPU and the versions, render-EXECUTOR.txt each render command's log.
#
# Environment: GR (default /tmp/gpu_render: outside the repository, so a warm machine keeps it between calls),
# KIT (.gpu: where the two parts are), SUITE (none: --exposures 3, i.e. syn-exp-3), SCENE (lamp-room-orbit),
# PRESET (paper), T_RENDER (420), CPUS (4), EXECUTOR (ray; local skips Ray), VARIANT (cuda_ad_rgb).
set -u
stage=${1:?usage: bash bench/gpu_render.sh a|b}
GR=${GR:-/tmp/gpu_render}
OUT=${OUT:-$GR/out}
KIT=${KIT:-.gpu}
mkdir -p "$GR/site" "$OUT"
el() { echo "[gpu_render $(date +%T)] $*"; }
case "$stage" in
  a)
    [ -f "$KIT/ra/site.tar.xz" ] || { el "no $KIT/ra/site.tar.xz: carry [\".gpu/ra\"] (packed by bench/gpu_render_kit.sh)"; exit 2; }
    tar -C "$GR/site" -xJf "$KIT/ra/site.tar.xz" && touch "$GR/site/.part-a" && el "part a unpacked into $GR/site"
    exit $?
    ;;
  b) ;;
  *) el "unknown stage $stage (a or b)"; exit 2 ;;
esac
[ -f "$KIT/rb/site.tar.xz" ] || { el "no $KIT/rb/site.tar.xz: carry [\".gpu/rb\"]"; exit 2; }
[ -f "$GR/site/.part-a" ] || { el "part a is not in $GR/site: the machine was not warm; run stage a, then b at once"; exit 3; }
tar -C "$GR/site" -xJf "$KIT/rb/site.tar.xz" || exit 4
PY=${PYTHON:-python3}
# the small wheels only where this Python lacks the module (the machine's own versions stay)
missing=()
shopt -s nullglob
for w in "$KIT"/rb/whl/*.whl; do
  name=$(basename "$w" | cut -d- -f1 | tr '[:upper:]' '[:lower:]')
  case "$name" in
    pyyaml) mod=yaml ;; protobuf) mod=google.protobuf ;; rpds_py) mod=rpds ;;
    jsonschema_specifications) mod=jsonschema_specifications ;; charset_normalizer) mod=charset_normalizer ;;
    *) mod=$name ;;
  esac
  PYTHONPATH="$GR/site" "$PY" -c "import $mod" 2>/dev/null || missing+=("$w")
done
if [ ${#missing[@]} -gt 0 ]; then
  el "installing ${#missing[@]} missing: $(for w in "${missing[@]}"; do basename "$w" | cut -d- -f1; done | tr '\n' ' ')"
  "$PY" -m pip install -q --no-index --no-deps --no-compile --target "$GR/site" "${missing[@]}" || exit 5
fi
export PYTHONPATH="$GR/site:$PWD"
VARIANT=${VARIANT:-cuda_ad_rgb}
el "environment"
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader 2>&1 | tee "$OUT/gpu.txt"
VARIANT=$VARIANT "$PY" - <<'EOF' 2>&1 | tee "$OUT/env.txt"
import os
import drjit as dr, mitsuba as mi, OpenImageIO as oiio, pyoidn, ray, torch  # noqa: F401
mi.set_variant(os.environ["VARIANT"])
print("mitsuba", mi.__version__, "variant", mi.variant(), "drjit", dr.__version__, "ray", ray.__version__,
      "oiio", getattr(oiio, "__version__", "?"), "torch", torch.__version__)
EOF
[ "${PIPESTATUS[0]}" -eq 0 ] || { el "the render stack does not load (env.txt)"; exit 6; }
SCENE=${SCENE:-lamp-room-orbit}
PRESET=${PRESET:-paper}
EXECUTOR=${EXECUTOR:-ray}
which="--exposures 3"
[ -n "${SUITE:-}" ] && which="--suite $SUITE"
render() {  # render EXECUTOR LOG
  el "benchgen make --scenes $SCENE --preset $PRESET --executor $1 --render-only, ${T_RENDER:-420} s"
  BENCHGEN_MI_VARIANT=$VARIANT timeout -k 10 "${T_RENDER:-420}" "$PY" -m benchgen make $which \
    --scenes "$SCENE" --preset "$PRESET" --executor "$1" --cpus-per-job "${CPUS:-4}" --render-only \
    --out "$GR/bench" > "$2" 2>&1
  local rc=$?
  tail -5 "$2"
  el "rc $rc"
  return $rc
}
used=$EXECUTOR
render "$EXECUTOR" "$OUT/render-$EXECUTOR.txt"
rc=$?
if [ "$EXECUTOR" = ray ] && [ $rc -ne 0 ] && ! grep -q "rendered render:" "$OUT/render-ray.txt" \
   && grep -qi "ray" "$OUT/render-ray.txt"; then
  el "Ray rendered nothing (render-ray.txt); the local executor instead"
  used=local
  render local "$OUT/render-local.txt"
  rc=$?
fi
"$PY" - "$GR/bench" "$SCENE" "$used" "$rc" "$OUT/render.json" <<'EOF'
import glob, json, os, re, statistics, sys
root, scene, executor, rc, out = sys.argv[1:6]
clips = glob.glob(os.path.join(root, "*", scene))
res = {"scene": scene, "executor": executor, "render_rc": int(rc), "clip": clips[0] if clips else None}
if clips:
    unit = os.path.join(clips[0], ".benchgen", "hdr_unit")
    secs = []
    for p in sorted(glob.glob(os.path.join(unit, "stats", "*.json"))):
        with open(p) as f:
            secs.append(float(json.load(f)["seconds"]))
    res["frames_on_disk"] = len(glob.glob(os.path.join(unit, "*.exr")))
    res["views_on_disk"] = len(glob.glob(os.path.join(unit, "views", "*", "*.exr")))
    res["frame_render_seconds"] = secs
    if secs:
        res["median_s_per_frame"] = statistics.median(secs)
        res["median_s_per_frame_after_first"] = statistics.median(secs[1:]) if len(secs) > 1 else None
    logs = glob.glob(os.path.join(os.path.dirname(out), "render-*.txt"))
    tasks = []
    for p in logs:
        for line in open(p):
            # "[benchgen] rendered render:SCENE:views:A-B (N frame(s), S s)"
            m = re.match(r"\[benchgen\] rendered render:.*:views:.* \((\d+) frame\(s\), ([\d.]+) s\)", line)
            if m:
                tasks.append((int(m.group(1)), float(m.group(2))))
    if tasks and sum(n for n, _ in tasks):
        res["views_s_per_test_frame"] = sum(s for _, s in tasks) / sum(n for n, _ in tasks)
with open(out, "w") as f:
    json.dump(res, f, indent=1)
print(json.dumps({k: v for k, v in res.items() if k != "frame_render_seconds"}))
EOF
exit $rc
