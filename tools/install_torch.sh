#!/usr/bin/env bash
# Install torch into the given interpreter's environment, preferring a local CPU wheel.
# Where pip's find-links holds a torch-*+cpu wheel for this Python (as on the facetex
# build machines), pin that exact version so pip takes the small CPU build instead of
# a multi-GB CUDA build. Elsewhere, install whatever `pip install torch` chooses.
set -euo pipefail
PY=${1:-python3}
if "$PY" -c "import torch" 2>/dev/null; then exit 0; fi
tag=$("$PY" -c 'import sys; print(f"cp{sys.version_info[0]}{sys.version_info[1]}")')
links=$("$PY" -m pip config get global.find-links 2>/dev/null || true)
links="$links ${PIP_FIND_LINKS:-}"
version=""
for d in $links; do
  d=${d#file://}
  [ -d "$d" ] || continue
  w=$(ls "$d"/torch-*+cpu-"$tag"-*.whl 2>/dev/null | sort -V | tail -n 1 || true)
  if [ -n "$w" ]; then
    version=$(basename "$w" | cut -d- -f2 | cut -d+ -f1)
    break
  fi
done
if [ -n "$version" ]; then
  echo "install_torch: using local CPU wheel torch==$version"
  "$PY" -m pip install -q "torch==$version"
else
  "$PY" -m pip install -q torch
fi
