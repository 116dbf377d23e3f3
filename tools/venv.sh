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
  echo "venv: installing the package into $VENV (builds the C firmware and simulator; about a minute the first time)" >&2
  "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check --upgrade pip >/dev/null
  log="$VENV/.pmlsm-install.log"
  (cd "$ROOT" && "$VENV/bin/python" -m pip install --disable-pip-version-check "$spec") >"$log" 2>&1 &
  pip_pid=$!
  t0=$SECONDS
  # a line every 10 s, so a first build is never silent (the step pip is at, from its log)
  while kill -0 "$pip_pid" 2>/dev/null; do
    for _ in 1 2 3 4 5 6 7 8 9 10; do kill -0 "$pip_pid" 2>/dev/null && sleep 1; done
    if kill -0 "$pip_pid" 2>/dev/null; then
      step=$(grep -E '^(Collecting|Building|Installing|  Building|  Running|  Preparing)' "$log" | tail -1 | cut -c1-70 || true)
      echo "venv: still installing ($((SECONDS - t0)) s${step:+: $step})" >&2
    fi
  done
  if ! wait "$pip_pid"; then
    tail -n 30 "$log" >&2
    echo "venv: pip install $spec failed (the end of its log is above; all of it in $log)" >&2
    exit 2
  fi
  echo "venv: installed in $((SECONDS - t0)) s" >&2
  echo "$want" > "$stamp"
fi

if [ "${1:-}" = "--python" ]; then
  echo "$VENV/bin/python"
  exit 0
fi
[ $# -gt 0 ] || { echo "usage: bash tools/venv.sh COMMAND [ARGS...] | --python" >&2; exit 2; }
export PATH="$VENV/bin:$PATH"
exec "$@"
