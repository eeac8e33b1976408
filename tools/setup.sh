#!/usr/bin/env bash
# Create .venv and install mocapdb with its test dependencies (PyPI only).
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3}
[ -x .venv/bin/python ] || "$PYTHON" -m venv .venv
.venv/bin/python -m pip install --quiet --upgrade pip
.venv/bin/python -m pip install --quiet -e '.[test,tools]'
# BlazePose, the default pose detector: the pinned MediaPipe wheel from the package index, converted
# to ONNX once (kept in ~/.cache/mocapdb/models, or $MOCAPDB_MODELS; nothing is fetched at run time)
.venv/bin/mocapdb models fetch
echo "installed: $(.venv/bin/mocapdb --version)"
