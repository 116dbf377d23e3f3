"""The packages' import rules, read from the sources (every import statement, at module
level or inside a function).

Layers, bottom to top: ``protocols`` (the object dictionary, its generators, serial
framing, the protocol libraries' loaders) < ``identification`` (the procedure over a
probe) < ``sim_fallback`` (the simulated drive in every world) < ``bench`` (the
supervisor) < ``simcampaign`` (campaigns and the paper reproduction, which use the bench's
sequence reader and replay runs through it).

- No module imports a package above its own. One exception, the composition root:
  the command line (``bench/cli.py``) offers ``bench campaign`` and may import
  ``simcampaign``.
- No module imports another package's private module (``pkg._mod``) or private name
  (``from pkg.mod import _name``); the scripts in ``tools/``, ``examples/`` and
  ``benchmarks/`` use the packages' public API too. Tests may look inside (they are
  white-box where they need to be).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
LAYERS = {"protocols": 0, "identification": 1, "sim_fallback": 2, "bench": 3,
          "simcampaign": 4}
#: module -> packages above it that it may import (the composition root)
COMPOSITION_ROOTS = {"bench/cli.py": {"simcampaign"}}
SCRIPT_DIRS = ("tools", "examples", "benchmarks")


def _imports(path: Path) -> list[tuple[int, str, list[str]]]:
    """(line, absolute module, imported names) of every import in ``path``."""
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    rel = path.relative_to(REPO).with_suffix("")
    pkg_parts = list(rel.parts[:-1]) if rel.name != "__init__" else list(rel.parts[:-1])
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                out.append((node.lineno, a.name, []))
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg_parts[:len(pkg_parts) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            out.append((node.lineno, mod, [a.name for a in node.names]))
    return out


def _violations(path: Path, own: str | None) -> list[str]:
    """What ``path`` (in package ``own``, or a script when None) imports against the
    rules, one line each."""
    where = path.relative_to(REPO).as_posix()
    bad = []
    for line, mod, names in _imports(path):
        top = mod.split(".")[0]
        if top not in LAYERS or top == own:
            continue
        if own is not None and LAYERS[top] > LAYERS[own] and \
                top not in COMPOSITION_ROOTS.get(where, set()):
            bad.append(f"{where}:{line}: {own} imports {mod}, a layer above it")
        parts = mod.split(".")[1:]
        if any(p.startswith("_") for p in parts):
            bad.append(f"{where}:{line}: imports {mod}, a private module of {top}")
        for n in names:
            if n.startswith("_") and n != "__version__":
                bad.append(f"{where}:{line}: imports {n} from {mod}, private to {top}")
    return bad


def _sources() -> list[tuple[Path, str | None]]:
    out: list[tuple[Path, str | None]] = []
    for pkg in LAYERS:
        out += [(p, pkg) for p in sorted((REPO / pkg).rglob("*.py"))
                if "generated" not in p.parts or pkg == "protocols"]
    for d in SCRIPT_DIRS:
        out += [(p, None) for p in sorted((REPO / d).rglob("*.py"))]
    return out


def test_no_upward_import_and_no_other_packages_private_module() -> None:
    files = _sources()
    assert len(files) > 60
    bad = [v for p, own in files for v in _violations(p, own)]
    assert not bad, "import rules broken:\n" + "\n".join(bad)


@pytest.mark.parametrize("text, own, expect", [
    ("from bench import Drive\n", "sim_fallback", "a layer above it"),
    ("import simcampaign\n", "bench", "a layer above it"),
    ("from sim_fallback._lib import FwConfig\n", "bench", "private module of sim_fallback"),
    ("from sim_fallback import _lib\n", "bench", "private to sim_fallback"),
    ("from bench._report import plotly_page_parts\n", None, "private module of bench"),
    ("def f():\n    from protocols._od import load\n", "sim_fallback", "private module"),
    ("from . import _lib\n", "sim_fallback", None),
    ("from protocols import load_od\n", "bench", None),
])
def test_the_rules_catch_what_they_forbid(tmp_path: Path, text: str, own: str | None,
                                          expect: str | None) -> None:
    """The checker on made-up modules: each forbidden kind is caught, allowed ones are
    not (a checker that cannot fail would pass the real tree too)."""
    d = REPO / (own or "tools")
    probe = d / f"_import_rule_probe_{tmp_path.name}.py"
    probe.write_text(text, encoding="utf-8")
    try:
        got = _violations(probe, own)
    finally:
        probe.unlink()
    if expect is None:
        assert got == []
    else:
        assert len(got) == 1 and expect in got[0], got
