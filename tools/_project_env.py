"""Imported first by every ``tools/`` script: they need the project's environment (numpy,
the simulator library, the bench). Run from a plain system Python (``python3
tools/x.py`` on a stock Debian, where none of it is installed), the script says so in one
line and how to run it, exit 2, instead of a traceback."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

_NEEDED = ("numpy", "yaml", "canopen", "can", "jsonschema")
_missing = [m for m in _NEEDED if importlib.util.find_spec(m) is None]
if _missing:
    script = Path(sys.argv[0]).name if sys.argv and sys.argv[0] else "this tool"
    args = " ".join(sys.argv[1:])
    print(f"tools/{script}: {', '.join(_missing)} not importable by {sys.executable}: run it "
          f"in the project's environment: bash tools/venv.sh python tools/{script}"
          + (f" {args}" if args else "") + " (or .venv/bin/python tools/" + script
          + " after the README's first command)", file=sys.stderr)
    raise SystemExit(2)
