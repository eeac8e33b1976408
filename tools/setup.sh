#!/usr/bin/env bash
# Create .venv and install mocapdb with its test and tools extras at the locked versions (PyPI only).
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3}
[ -x .venv/bin/python ] || "$PYTHON" -m venv .venv
# requirements.lock: every package at an exact version with its sha256 hashes, pip and the build backend
# included (tools/lock.py solves it from pyproject.toml's ranges; docs/install.md, "The lock")
.venv/bin/python -m pip install --quiet --require-hashes -r requirements.lock
.venv/bin/python -m pip install --quiet --no-deps --no-build-isolation -e .
# BlazePose, the default pose detector, and the hand and face landmark models of `detect --hands --face`:
# the pinned MediaPipe wheel from the package index, converted to ONNX once (kept in ~/.cache/mocapdb/models,
# or $MOCAPDB_MODELS; nothing is fetched at run time)
.venv/bin/mocapdb models fetch full hands face
echo "installed: $(.venv/bin/mocapdb --version)"
