#!/usr/bin/env bash
# Install PyTorch into the environment of the given Python without ever pulling the
# multi-GB CUDA build onto a machine that has no NVIDIA GPU.
#   1. torch already importable          -> nothing to do
#   2. an NVIDIA GPU is present          -> the default (CUDA) build from the index
#   3. a CPU wheel visible to pip's local configuration (find-links) -> that wheel
#   4. otherwise                          -> PyTorch's CPU-only wheel index
set -euo pipefail
PY=${1:-python}
TORCH_VERSION=${TORCH_VERSION:-2.13.0}
if "$PY" -c "import torch" >/dev/null 2>&1; then
  echo "torch already installed: $("$PY" -c 'import torch; print(torch.__version__)')"
  exit 0
fi
if command -v nvidia-smi >/dev/null 2>&1 && nvidia-smi -L >/dev/null 2>&1; then
  exec "$PY" -m pip install "torch==${TORCH_VERSION}"
fi
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
if "$PY" -m pip download --no-index --no-deps -d "$tmp" "torch==${TORCH_VERSION}" >/dev/null 2>&1 \
   && ls "$tmp"/torch-*+cpu-*.whl >/dev/null 2>&1; then
  exec "$PY" -m pip install "$tmp"/torch-*.whl
fi
exec "$PY" -m pip install "torch==${TORCH_VERSION}" --index-url "${TORCH_CPU_INDEX:-https://download.pytorch.org/whl/cpu}"
