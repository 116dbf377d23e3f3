#!/usr/bin/env bash
# The whole test suite: installs the package with its test extra into the
# project's virtual environment (.venv, made by tools/venv.sh), builds all
# C with CMake, runs the C unit tests (ctest) and then pytest (Python tests,
# the Cortex-M4F cross build, the short fuzz runs, end-to-end protocol tests).
# Usage: bash tools/test_all.sh [extra pytest args]
set -euo pipefail
cd "$(dirname "$0")/.."

echo "== installing the package with its test extra into .venv (C core + simulated drive built by CMake) =="
PY=$(PMLSM_EXTRAS=test bash tools/venv.sh --python)

echo "== C build and unit tests (ctest) =="
cmake -S . -B build/test -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo >/dev/null
cmake --build build/test
ctest --test-dir build/test --output-on-failure

echo "== lint (ruff) =="
"$PY" -m ruff check bench sim_fallback protocols identification simcampaign tests benchmarks tools examples

echo "== Python tests (pytest) =="
export PMLSM_BUILD_DIR="$PWD/build/test"
"$PY" -m pytest "$@"
