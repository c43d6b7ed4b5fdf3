#!/usr/bin/env bash
# The whole GPU check of one lent-device session, in time slots that fit one 10-minute command. Run it on the
# CUDA machine from the repository root, after `bash bench/gpu_kit.sh CLIP` packed .gpu/ here (device run:
# carry [".gpu"]):
#
#   set -o pipefail; bash bench/gpu_session.sh 2>&1 | tee $OUT/log.txt
#
# Slots (seconds, environment variables): T_A env + `pytest -m gpu` (gsplat compiles its CUDA code on first
# use: 55-78 s on 16 cores), T_B one training at PRESET with ITERS iterations per stage, its render FPS, the
# FPS of that model split to FPS_COUNTS Gaussians and a profile of its stage-2 steps (STEPS_B, default
# train,fps,fps_scale,profile), T_C JOBS concurrent trainings of JOBS_ITERS iterations at the small preset. A
# slot that runs out is cut (its JSON then holds the steps it finished) and the next one starts; a gsplat that
# does not build stops the script after slot A. The JSON of each slot comes back as $OUT/{a,b,c}.json.
#
# PAPER_RUN=1 adds slot P: `m4dgs train --preset paper` at full length (11.0 min of phases on an H100, more than
# one command may run) into $GPU_RUN/paper, cut at T_P seconds. The run folder and gsplat's build live in GPU_RUN
# (default /tmp/gpu_run, outside the repository: the copy of the working tree comes back without ignored folders,
# while a warm machine keeps /tmp between calls; seen in the third session: the second call's first render took
# 0.4 s against the first call's 53 s build), so the same command again at once (within the machine's 30 s warm
# window) skips the build and resumes the run from its checkpoint. Two calls (T_A=100 T_P=465, then T_A=80 T_P=240)
# finished it. Run it with STEPS_A=env T_B=0 T_C=0 to spend a call on slot P alone (a slot given 0 s is skipped);
# $OUT/paper.txt says where the run stands (status.json: its seconds per phase), and once it is finished slot
# P2 (T_PP) writes $OUT/paper.json: the FPS of the paper-scale model and a profile of its late stage 2.
#
# Slot D (T_D seconds; runs when .gpu/old holds another commit's code, packed by `OLD=COMMIT bash bench/gpu_kit.sh`):
# a side-by-side timing of a code change on this GPU. bench/step_bench.py on slot B's run (stage 2 from its final
# model, AB_STEPS timed steps), with the packed commit's code and with this tree's in ABBA order (old new, new old,
# ...: a drift over the slot falls on both alike), AB_ROUNDS times each;
# the printed ms/step lines come back in $OUT/ab.txt.
set -u
T0=$(date +%s)
el() { echo "[gpu_session] $(($(date +%s) - T0)) s: $*"; }
GPU_RUN=${GPU_RUN:-/tmp/gpu_run}
mkdir -p "$GPU_RUN"
# the wheels, gsplat's build, the paper run and each slot's scratch folder all live in GPU_RUN
# a warm machine's second call finds them installed
[ -d "$GPU_RUN/site/gsplat" ] || python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target "$GPU_RUN/site" .gpu/whl/*.whl || exit 3
export PYTHONPATH=$GPU_RUN/site:$PWD TORCH_CUDA_ARCH_LIST=${TORCH_CUDA_ARCH_LIST:-9.0} MAX_JOBS=${MAX_JOBS:-16} PYTHONUNBUFFERED=1
export TORCH_EXTENSIONS_DIR=$GPU_RUN/torch_extensions
nvidia-smi -L
nvcc --version | tail -1
C=$(ls -d .gpu/clip/*/ | head -1)
OUT=${OUT:-/tmp/gpu_out}
mkdir -p "$OUT"
el "slot A: ${STEPS_A:-env,tests}"
timeout -k 5 "${T_A:-270}" python3 bench/gpu_check.py "$C" --out "$GPU_RUN/a" --steps "${STEPS_A:-env,tests}"
pkill -f pytest
cp "$GPU_RUN/a/gpu_check.json" "$OUT/a.json"
python3 -c "import json,sys; d=json.load(open(sys.argv[1])); sys.exit('gsplat_first_render_s' not in d['steps']['env'])" "$GPU_RUN/a/gpu_check.json" || { el "gsplat did not build"; exit 4; }
if [ "${PAPER_RUN:-0}" = 1 ]; then
  el "slot P: m4dgs train --preset paper (full length) into $GPU_RUN/paper, ${T_P:-480} s"
  timeout -k 5 "${T_P:-480}" python3 -m m4dgs train --clip "$C" --preset paper --device cuda --quiet --out "$GPU_RUN/paper"
  echo "rc $?" > "$OUT/paper.txt"
  cat "$GPU_RUN/paper/status.json" >> "$OUT/paper.txt" 2>/dev/null
  tail -2 "$GPU_RUN/paper/log.jsonl" >> "$OUT/paper.txt" 2>/dev/null
  # once the run is finished: FPS of the paper-scale model it trained and a profile of its late stage 2
  if grep -q '"stage": "done"' "$GPU_RUN/paper/status.json" 2>/dev/null && [ "${T_PP:-150}" != 0 ]; then
    el "slot P2: FPS and stage-2 profile of the finished paper run, ${T_PP:-150} s"
    timeout -k 5 "${T_PP:-150}" python3 bench/gpu_check.py "$C" --out "$GPU_RUN/p" --preset paper --steps fps,profile --run "$GPU_RUN/paper"
    cp "$GPU_RUN/p/gpu_check.json" "$OUT/paper.json" 2>/dev/null
  fi
fi
# a slot given 0 seconds is skipped (`timeout 0` would mean no limit at all)
if [ "${T_B:-200}" != 0 ]; then
  el "slot B: ${PRESET:-paper} training, ${ITERS:-1000} iterations per stage, ${STEPS_B:-train,fps,fps_scale,profile}"
  timeout -k 5 "${T_B:-200}" python3 bench/gpu_check.py "$C" --out "$GPU_RUN/b" --preset "${PRESET:-paper}" --iters "${ITERS:-1000}" \
    --steps "${STEPS_B:-train,fps,fps_scale,profile}" --fps-counts "${FPS_COUNTS:-50000,150000,300000}"
  pkill -f train_bench.py
  cp "$GPU_RUN/b/gpu_check.json" "$OUT/b.json"
fi
if [ "${T_C:-100}" != 0 ]; then
  el "slot C: ${JOBS:-1,2,4} concurrent small trainings of ${JOBS_ITERS:-300} iterations per stage"
  timeout -k 5 "${T_C:-100}" python3 bench/gpu_check.py "$C" --out "$GPU_RUN/c" --preset small --steps jobs --jobs "${JOBS:-1,2,4}" --jobs-iters "${JOBS_ITERS:-300}"
  pkill -f train_bench.py
  cp "$GPU_RUN/c/gpu_check.json" "$OUT/c.json" 2>/dev/null
fi
if [ -d .gpu/old/m4dgs ] && [ "${T_D:-120}" != 0 ] && [ -f "$GPU_RUN/b/run/model/final.pt" ]; then
  el "slot D: step_bench, $(cat .gpu/old/COMMIT 2>/dev/null) against this tree, ${AB_ROUNDS:-2} rounds, ${T_D:-120} s"
  start=$(python3 -c "import sys; sys.path.insert(0, 'bench'); from gpu_check import profile_start; print(profile_start(sys.argv[1], int(sys.argv[2])))" "$GPU_RUN/b/run" "${AB_STEPS:-40}")
  ab() { PYTHONPATH=$GPU_RUN/site:$1 python3 "$1/bench/step_bench.py" "$C" "$GPU_RUN/b/run" --preset "${PRESET:-paper}" \
    --stage stage2 --from-final --start "$start" --steps "${AB_STEPS:-40}" --device cuda 2>&1 | grep ms/step | sed "s|^|$2 |"; }
  ( for r in $(seq "${AB_ROUNDS:-2}"); do if [ $((r % 2)) = 1 ]; then ab "$PWD/.gpu/old" old; ab "$PWD" new; else ab "$PWD" new; ab "$PWD/.gpu/old" old; fi; done ) > "$OUT/ab.txt" &
  abpid=$!
  # the time limit's watcher writes nowhere (so it never holds the caller's pipe open) and goes when the slot ends
  # (the fourth session's first call waited 80 s on a watcher's sleep after slot D had finished)
  ( sleep "${T_D:-120}"; kill $abpid 2>/dev/null; pkill -f step_bench.py ) >/dev/null 2>&1 &
  watcher=$!
  wait $abpid
  pkill -P $watcher 2>/dev/null; kill $watcher 2>/dev/null
  cat "$OUT/ab.txt"
fi
nvidia-smi --query-gpu=name,memory.used,memory.total --format=csv
el "done"
