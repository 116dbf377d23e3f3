#!/usr/bin/env bash
# Run a command inside the project's virtual environment (.venv at the top of the
# checkout), creating it and installing the package first when needed. Works on a
# stock Debian/Ubuntu Python, where `pip install` outside a venv is refused.
#
#   bash tools/venv.sh bench run sequences/paper_load_step.yaml --sim
#   bash tools/venv.sh --python          # print the venv's python (for scripts)
#
# Environment: PYTHON (interpreter to create the venv from, default python3),
# PMLSM_EXTRAS (pip extras to install, e.g. "test"), PMLSM_VENV (venv folder).
# Exit 2 with one line when no venv can be made (python3-venv missing, not root).
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
VENV="${PMLSM_VENV:-$ROOT/.venv}"
PY="${PYTHON:-python3}"
EXTRAS="${PMLSM_EXTRAS:-}"

if [ ! -x "$VENV/bin/python" ]; then
  if ! "$PY" -m venv "$VENV" >/dev/null 2>&1; then
    rm -rf "$VENV"
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
      echo "venv: installing python3-venv (Debian/Ubuntu)" >&2
      (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq python3-venv) >/dev/null \
        || { echo "venv: apt-get install python3-venv failed; install it and rerun" >&2; exit 2; }
      "$PY" -m venv "$VENV"
    else
      echo "venv: '$PY -m venv' failed; install python3-venv (sudo apt-get install python3-venv) and rerun" >&2
      exit 2
    fi
  fi
fi

# (re)install when the sources changed since the last install
spec="."; [ -n "$EXTRAS" ] && spec=".[$EXTRAS]"
stamp="$VENV/.pmlsm-installed"
want="$spec $(cd "$ROOT" && git rev-parse HEAD 2>/dev/null || echo nogit) $(cd "$ROOT" && git status --porcelain -- firmware_c sim_fallback protocols bench CMakeLists.txt pyproject.toml 2>/dev/null | md5sum | cut -c1-8)"
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  echo "venv: installing the package into $VENV (builds the C firmware and simulator)" >&2
  "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check --upgrade pip >/dev/null
  (cd "$ROOT" && "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check "$spec") \
    || { echo "venv: pip install $spec failed (see the output above)" >&2; exit 2; }
  echo "$want" > "$stamp"
fi

if [ "${1:-}" = "--python" ]; then
  echo "$VENV/bin/python"
  exit 0
fi
[ $# -gt 0 ] || { echo "usage: bash tools/venv.sh COMMAND [ARGS...] | --python" >&2; exit 2; }
export PATH="$VENV/bin:$PATH"
exec "$@"
