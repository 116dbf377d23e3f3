"""The docs describe the code as it is: every C function or type (`fw_...`, `co_...`,
`sim_...`) they name exists in the sources, every Python symbol (`bench._session.run_live`)
resolves, and every source file (`fw_mon.c`, `bench/_scope.py`) named in the docs or in a
Python docstring exists. History (what a name used to be) belongs in CHANGELOG.md, which
is not checked."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCS = sorted(ROOT.glob("docs/*.md")) + [ROOT / "README.md"]
SKIP = {".venv", ".git", "build", "node_modules"}


def _repo_files() -> list[str]:
    return [str(p.relative_to(ROOT)) for p in ROOT.rglob("*")
            if p.is_file() and not SKIP & set(p.relative_to(ROOT).parts)]


SELF = str(Path(__file__).resolve().relative_to(ROOT))  # its examples are stale on purpose
FILES = [f for f in _repo_files() if f != SELF]
SOURCES = " ".join((ROOT / f).read_text(errors="replace") for f in FILES
                   if f.endswith((".c", ".h", ".py", ".cmake", ".txt", ".yaml", ".sh", ".ld")))
CODE = re.compile(r"`([^`\n]+)`")
C_NAME = re.compile(r"(?<![\w./-])((?:fw|co|sim|g4|emu|slcan|nvm)_[a-z0-9_]*[a-z0-9])\b")
PY_NAME = re.compile(r"(?<![\w./-])((?:bench|sim_fallback|protocols)(?:\.[A-Za-z_]\w*)+)")
SRC_FILE = re.compile(r"(?<![\w<$*{.])([\w/-]+\.(?:py|c|h))\b")


def _code_spans(path: Path) -> list[str]:
    return CODE.findall(path.read_text(encoding="utf-8", errors="replace"))


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: p.name)
def test_c_names_in_the_docs_exist(doc: Path) -> None:
    missing = sorted({n for span in _code_spans(doc) for n in C_NAME.findall(span)
                      if not re.search(rf"\b{re.escape(n)}\b", SOURCES)})
    assert not missing, f"{doc.name} names what the sources do not have: {missing}"


def _resolves(dotted: str) -> bool:
    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        try:
            for attr in parts[i:]:
                obj = getattr(obj, attr)
        except AttributeError:
            return False
        return True
    return False


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: p.name)
def test_python_symbols_in_the_docs_resolve(doc: Path) -> None:
    missing = sorted({n for span in _code_spans(doc) for n in PY_NAME.findall(span)
                      if not _resolves(n)})
    assert not missing, f"{doc.name} names Python symbols that do not exist: {missing}"


def test_source_files_named_in_docs_and_docstrings_exist() -> None:
    texts = DOCS + [ROOT / f for f in FILES if f.endswith(".py")]
    missing = {}
    for t in texts:
        for span in _code_spans(t):
            for f in SRC_FILE.findall(span):
                if not any(x == f or x.endswith("/" + f) for x in FILES):
                    missing.setdefault(str(t.relative_to(ROOT)), set()).add(f)
    assert not missing, f"files named but not in the repository: {missing}"


def test_the_check_catches_a_stale_name(tmp_path: Path) -> None:
    """The rules find a removed function, a wrong Python path and a missing file."""
    spans = CODE.findall("call `fw_step_adc_into()` then `bench._session.no_such` in "
                         "`firmware_c/src/fw_gone.c`")
    assert [n for s in spans for n in C_NAME.findall(s)
            if not re.search(rf"\b{n}\b", SOURCES)] == ["fw_step_adc_into"]
    assert not _resolves("bench._session.no_such") and _resolves("bench._session.run_live")
    assert SRC_FILE.findall(spans[2]) == ["firmware_c/src/fw_gone.c"]
