#!/usr/bin/env bash
# One-time set-up, idempotent: Debian packages, a virtual environment in .venv, the project and its pinned deps.
# Used by `make demo` and `make test` (and so by .ci/run). Safe to re-run: finished steps are skipped quickly.
set -euo pipefail
cd "$(dirname "$0")/.."

PY=${PYTHON:-python3}
SUDO=""
if [ "$(id -u)" != "0" ] && command -v sudo >/dev/null 2>&1; then SUDO="sudo"; fi

# Mitsuba's fast llvm_ad_rgb variant needs LLVM 19 (the preinstalled LLVM 15 crashes it); ffmpeg for videos.
need_apt=()
ls /usr/lib/x86_64-linux-gnu/libLLVM.so.19* >/dev/null 2>&1 || ls /usr/lib/*/libLLVM*19* >/dev/null 2>&1 || need_apt+=(libllvm19)
# the viewer's browser test (tests/viewer/test_browser.py) drives a headless chromium through playwright
command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1 || need_apt+=(chromium)
# xz: tar -J in bench/gpu_render.sh and its test (tests/test_bench_gpu_render.py)
command -v xz >/dev/null 2>&1 || need_apt+=(xz-utils)
if [ ${#need_apt[@]} -gt 0 ]; then
  if command -v apt-get >/dev/null 2>&1; then
    echo "[setup] installing Debian packages: ${need_apt[*]}"
    $SUDO apt-get update -qq
    $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${need_apt[@]}" >/dev/null
  else
    echo "[setup] no apt-get: Mitsuba will fall back to its scalar_rgb variant (about 3x slower) and the viewer's browser test is skipped without chromium" >&2
  fi
fi

if [ ! -x .venv/bin/python ]; then
  echo "[setup] creating .venv"
  "$PY" -m venv .venv
fi
stamp=.venv/.m4dgs-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  echo "[setup] installing the project (torch pinned to 2.13.0; CPU wheel when one is on disk)"
  .venv/bin/pip install -q --upgrade pip
  # Pin torch first and on its own: a looser requirement would pull gigabytes of CUDA packages on CPU machines.
  # Elsewhere, point TORCH_INDEX_URL at the CPU (or CUDA) wheel index of your choice.
  if [ -n "${TORCH_INDEX_URL:-}" ]; then
    .venv/bin/pip install -q "torch==2.13.0" --index-url "$TORCH_INDEX_URL"
  else
    .venv/bin/pip install -q "torch==2.13.0"
  fi
  .venv/bin/pip install -q -e ".[test]"
  touch "$stamp"
fi
echo "[setup] ready: $(.venv/bin/python -c 'import torch, mitsuba; print("torch", torch.__version__, "/ mitsuba", mitsuba.__version__)')"
