"""Test records: who and what was tested in a run, and the results store across runs.

Every run records the device under test as the drive says it is (0x1018 vendor id,
product code, revision, serial number; firmware version 0x2040, build id 0x2041, device
name 0x1008; what it is, 0x2090:1, and its board, 0x2090:2), never as typed, and the
operator, station and fixture of the bench (``bench run --operator/--station/--fixture``,
else ``BENCH_OPERATOR`` / ``BENCH_STATION`` / ``BENCH_FIXTURE``, else the login name /
the host name / ""). They go into ``summary.json`` (``dut``, ``record``), ``meta.json``
and the JUnit testsuite properties.

The results store is one SQLite file beside the run folders, ``<runs>/results.sqlite``
(WAL mode): a row per run in ``runs`` and a row per expectation in ``expectations``,
written at the end of every run in one transaction, safe with several bench processes
writing at once. ``bench results`` queries it; ``bench results --rebuild`` re-creates
it from the run folders' ``summary.json`` (and ``meta.json`` for runs recorded before
the store existed), so a deleted or corrupt store is recoverable.
"""

from __future__ import annotations

import contextlib
import csv
import getpass
import io
import json
import math
import os
import random
import socket
import sqlite3
import time
import xml.etree.ElementTree as ET
from collections.abc import Callable, Iterator, Mapping
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

#: the store's file name in the runs root
STORE_NAME = "results.sqlite"
#: version of the store's tables (``PRAGMA user_version``)
SCHEMA_VERSION = 1
VERDICTS = ("passed", "failed", "aborted")
#: longest operator / station / fixture text
MAX_FIELD_CHARS = 100
#: the station fields: option -> environment variable
STATION_ENV = {"operator": "BENCH_OPERATOR", "station": "BENCH_STATION",
               "fixture": "BENCH_FIXTURE"}

# ---- the record of a run ----------------------------------------------------------------


class RecordFieldError(ValueError):
    """An operator / station / fixture value that cannot be recorded (one line naming
    the option)."""


def _login_name() -> str:
    try:
        return getpass.getuser()
    except Exception:  # noqa: BLE001 - no user name in this environment
        return ""


def _host_name() -> str:
    try:
        return socket.gethostname()
    except OSError:
        return ""


def check_field(option: str, value: str, source: str = "") -> str:
    """``value`` as recorded: printable, at most :data:`MAX_FIELD_CHARS` characters,
    surrounding blanks removed. Raises :class:`RecordFieldError` naming ``--option``
    (and ``source``, e.g. the environment variable it came from)."""
    where = f"--{option}" + (f" (from {source})" if source else "")
    if not isinstance(value, str):
        raise RecordFieldError(f"{where}: {value!r} is not text")
    v = value.strip()
    bad = next((i for i, c in enumerate(v) if not c.isprintable()), None)
    if bad is not None:
        raise RecordFieldError(f"{where}: {v[:40]!r}: character {bad + 1} (U+{ord(v[bad]):04X}) "
                               f"is not printable; printable text, at most {MAX_FIELD_CHARS} "
                               "characters")
    if len(v) > MAX_FIELD_CHARS:
        raise RecordFieldError(f"{where}: {len(v)} characters; at most {MAX_FIELD_CHARS}")
    return v


def station_fields(operator: str | None = None, station: str | None = None,
                   fixture: str | None = None,
                   environ: Mapping[str, str] | None = None) -> dict[str, str]:
    """Operator, station and fixture of a run: the value given, else the environment
    variable (:data:`STATION_ENV`), else the login name / the host name / "".

    Raises
    ------
    RecordFieldError
        A given or environment value that is not printable or is too long.
    """
    env = os.environ if environ is None else environ
    given = {"operator": operator, "station": station, "fixture": fixture}
    defaults: dict[str, Callable[[], str]] = {"operator": _login_name, "station": _host_name,
                                              "fixture": str}
    out = {}
    for key, var in STATION_ENV.items():
        if given[key] is not None:
            out[key] = check_field(key, given[key])
        elif env.get(var) is not None:
            out[key] = check_field(key, env[var], var)
        else:  # what the system says: never refused, at most shortened
            d = defaults[key]().strip()
            out[key] = "".join(c for c in d if c.isprintable())[:MAX_FIELD_CHARS]
    return out


def utc_stamp(t: datetime | None = None) -> str:
    """``2026-01-02T03:04:05.123456Z``: UTC, fixed width (sorts as text)."""
    t = t or datetime.now(timezone.utc)
    return t.astimezone(timezone.utc).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def dut_fields(ident: Mapping[str, Any] | None, kind: Mapping[str, Any],
               error: str | None = None) -> dict[str, Any]:
    """The device under test as the drive said it is: ``ident`` from
    :meth:`bench.Drive.identity`, ``kind`` from :func:`bench._session.drive_kind`.
    A field the drive did not answer is None and ``error`` says why."""
    ident = ident or {}

    def num(k: str) -> int | None:
        v = ident.get(k)
        return int(v) if isinstance(v, int) and not isinstance(v, bool) else None

    def text(k: str) -> str | None:
        v = ident.get(k)
        return None if v is None else str(v)

    return {"vendor_id": num("vendor_id"), "product_code": num("product_code"),
            "revision": num("revision"), "serial": num("serial"),
            "firmware_version": text("firmware_version"), "build_id": text("build_id"),
            "device_name": text("device_name"), "software_version": text("software_version"),
            "node_id": num("node_id"), "kind": str(kind.get("drive", "unknown")),
            "board": str(kind.get("board", "")),
            "error": error if error is not None or ident else "identity not read"}


def verdict_of(result: Any, interrupted: BaseException | None = None
               ) -> tuple[str, str, int]:
    """``(verdict, exit reason, exit code)`` of a run, as ``bench run`` ends it: passed
    (0); failed (1: an expectation failed, or the safe state was not confirmed after the
    sequence ran to its end); aborted (the sequence did not run to its end: 130
    interrupted, else 3)."""
    if result.aborted or interrupted is not None:
        if isinstance(interrupted, KeyboardInterrupt):
            return "aborted", "interrupted (Ctrl-C / SIGTERM)", 130
        why = result.error or (" ".join(f"{type(interrupted).__name__}: "
                                        f"{interrupted}".split()) if interrupted else "aborted")
        return "aborted", why, 3
    if result.passed:
        n = len(result.expectations)
        nj = sum(1 for e in result.expectations if not e.judged)
        return "passed", (f"{n - nj} of {n} expectations passed" + (
            f", {nj} not judged" if nj else "") if n else "ran to its end (no expectations)"), 0
    failed = [e.name for e in result.expectations if e.judged and not e.passed]
    if failed:
        shown = ", ".join(failed[:3]) + (f" and {len(failed) - 3} more" if len(failed) > 3
                                         else "")
        return "failed", f"{len(failed)} expectation(s) failed: {shown}", 1
    if result.safe_state and result.safe_state != "disabled":
        return "failed", result.safe_state, 1
    return "failed", result.error or "failed", 1


def junit_properties(record: Mapping[str, Any]) -> list[tuple[str, str]]:
    """The test-record properties of a run's JUnit testsuite (``record``: what
    :func:`bench._session.run_sequence` returns as ``RunOutput.record``)."""
    dut = record.get("dut") or {}
    rec = record.get("record") or {}

    def hex32(v: Any) -> str:
        return f"0x{v:08X}" if isinstance(v, int) else ""

    props = [("vendor_id", hex32(dut.get("vendor_id"))),
             ("product_code", hex32(dut.get("product_code"))),
             ("revision_number", hex32(dut.get("revision"))),
             ("serial_number", "" if dut.get("serial") is None else str(dut["serial"])),
             ("firmware_version", dut.get("firmware_version") or ""),
             ("build_id", dut.get("build_id") or ""),
             ("device_name", dut.get("device_name") or ""),
             ("operator", rec.get("operator", "")), ("station", rec.get("station", "")),
             ("fixture", rec.get("fixture", "")), ("started_utc", rec.get("started_utc", "")),
             ("motor", rec.get("motor", "")), ("sequence_file", rec.get("sequence_file", "")),
             ("sequence_sha256", rec.get("sequence_sha256", "")),
             ("params", json.dumps(rec.get("params") or {}, sort_keys=True))]
    return [(k, str(v)) for k, v in props]


def add_junit_properties(path: str | Path, records: list[Mapping[str, Any]]) -> None:
    """Add each run's test-record properties to the ``run`` testcase of its testsuite (in
    order) of the JUnit file ``path`` (written by :func:`bench._report.write_junit`; the
    testsuite's own properties stay what it writes: drive, simulated, fallback, board)."""
    tree = ET.parse(path)
    suites = tree.getroot().findall("testsuite")
    for suite, rec in zip(suites, records, strict=False):
        run = next((c for c in suite.findall("testcase") if c.get("name") == "run"), None)
        if run is None:
            continue
        props = run.find("properties")
        if props is None:
            props = ET.Element("properties")
            run.insert(0, props)
        have = {p.get("name") for p in props}
        for k, v in junit_properties(rec):
            if k not in have:
                ET.SubElement(props, "property", name=k, value=v)
    ET.indent(tree.getroot())
    tmp = Path(str(path) + ".tmp")
    tree.write(tmp, encoding="utf-8", xml_declaration=True)
    os.replace(tmp, path)


# ---- the results store ------------------------------------------------------------------


class StoreError(RuntimeError):
    """The results store is missing, corrupt, or not a results store (one line)."""


#: the runs table's columns, in order (name, SQL type)
RUN_COLUMNS: tuple[tuple[str, str], ...] = (
    ("run_dir", "TEXT NOT NULL UNIQUE"), ("sequence", "TEXT NOT NULL"),
    ("sequence_file", "TEXT"), ("sequence_sha256", "TEXT"), ("params", "TEXT"),
    ("motor", "TEXT"), ("vendor_id", "INTEGER"), ("product_code", "INTEGER"),
    ("revision", "INTEGER"), ("serial", "INTEGER"), ("firmware_version", "TEXT"),
    ("build_id", "TEXT"), ("device_name", "TEXT"), ("drive_kind", "TEXT"), ("board", "TEXT"),
    ("fallback", "INTEGER"), ("operator", "TEXT"), ("station", "TEXT"), ("fixture", "TEXT"),
    ("started_utc", "TEXT NOT NULL"), ("finished_utc", "TEXT"), ("duration_s", "REAL"),
    ("verdict", "TEXT NOT NULL CHECK (verdict IN ('passed', 'failed', 'aborted'))"),
    ("exit_reason", "TEXT"), ("exit_code", "INTEGER"), ("n_expectations", "INTEGER"),
    ("n_failed", "INTEGER"), ("bench_version", "TEXT"), ("recorded_utc", "TEXT"),
)
EXPECT_COLUMNS: tuple[tuple[str, str], ...] = (
    ("name", "TEXT"), ("metric", "TEXT"), ("measured", "REAL"), ("criterion", "TEXT"),
    ("status", "TEXT"), ("window_t0_s", "REAL"), ("window_t1_s", "REAL"),
    ("message", "TEXT"), ("paper", "REAL"),
)
_DDL = (
    "CREATE TABLE IF NOT EXISTS runs (id INTEGER PRIMARY KEY, "
    + ", ".join(f"{n} {t}" for n, t in RUN_COLUMNS) + ")",
    "CREATE TABLE IF NOT EXISTS expectations (run_id INTEGER NOT NULL REFERENCES runs(id) "
    "ON DELETE CASCADE, idx INTEGER NOT NULL, "
    + ", ".join(f"{n} {t}" for n, t in EXPECT_COLUMNS) + ", PRIMARY KEY (run_id, idx))",
    "CREATE INDEX IF NOT EXISTS runs_started ON runs (started_utc)",
    "CREATE INDEX IF NOT EXISTS runs_serial ON runs (serial)",
    "CREATE INDEX IF NOT EXISTS runs_motor ON runs (motor)",
    "CREATE INDEX IF NOT EXISTS runs_sequence ON runs (sequence)",
)


def store_path(runs_root: str | Path) -> Path:
    """``<runs_root>/results.sqlite``."""
    return Path(runs_root) / STORE_NAME


def _busy(e: BaseException) -> bool:
    return isinstance(e, sqlite3.OperationalError) and any(
        w in str(e).lower() for w in ("locked", "busy"))


def _connect(path: Path, create: bool, timeout_s: float = 30.0) -> sqlite3.Connection:
    """A connection, autocommit (transactions are explicit); with ``create`` (writers) the
    store is switched to WAL mode. Without ``create`` (queries), a missing file is a
    :class:`StoreError` (never created by a query) and nothing in the file is changed."""
    if not create and not path.is_file():
        what = "no such file" if not path.exists() else "not a file"
        raise StoreError(f"{path}: no results store ({what}); it is written by every "
                         "'bench run' under that runs folder, and "
                         "'bench results --rebuild' builds it from the run folders")
    uri = path.resolve().as_uri() + ("?mode=rwc" if create else "?mode=rw")
    con = sqlite3.connect(uri, uri=True, timeout=timeout_s, isolation_level=None)
    try:
        con.execute(f"PRAGMA busy_timeout = {int(timeout_s * 1000)}")
        if con.execute("PRAGMA journal_mode").fetchone()[0].lower() != "wal" and create:
            con.execute("PRAGMA journal_mode = WAL")
        con.execute("PRAGMA foreign_keys = ON")
    except BaseException:
        con.close()
        raise
    return con


def _check_tables(con: sqlite3.Connection, path: Path) -> None:
    """Raise :class:`StoreError` unless the tables are the results store's."""
    ver = con.execute("PRAGMA user_version").fetchone()[0]
    if ver > SCHEMA_VERSION:
        raise StoreError(f"{path}: written by a newer bench (store version {ver}, this bench "
                         f"reads {SCHEMA_VERSION})")
    for table, cols in (("runs", RUN_COLUMNS), ("expectations", EXPECT_COLUMNS)):
        have = {r[1] for r in con.execute(f"PRAGMA table_info({table})")}
        missing = [c for c, _ in cols if c not in have]
        if missing:
            raise StoreError(f"{path}: not a results store (table {table!r} "
                             + ("missing" if not have else f"lacks {', '.join(missing)}")
                             + "); 'bench results --rebuild' re-creates it from the run "
                               "folders")


def _create(con: sqlite3.Connection, path: Path) -> None:
    """Create the tables if absent (inside the caller's transaction) and check them."""
    for stmt in _DDL:
        con.execute(stmt)
    if con.execute("PRAGMA user_version").fetchone()[0] == 0:
        con.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")
    _check_tables(con, path)


def _begin(path: Path, create: bool, attempts: int = 6) -> sqlite3.Connection:
    """A connection holding the store's write lock (``BEGIN IMMEDIATE``: two writers
    queue for it instead of failing at commit). A store another process holds longer
    than the busy timeout, or switching a new store to WAL beside another process, is
    retried a few times."""
    for attempt in range(attempts):
        con = None
        try:
            con = _connect(path, create)
            con.execute("BEGIN IMMEDIATE")
            return con
        except sqlite3.OperationalError as e:
            if con is not None:
                con.close()
            if not _busy(e) or attempt == attempts - 1:
                raise
            time.sleep(0.05 + random.random() * 0.2 * (attempt + 1))
        except BaseException:
            if con is not None:
                con.close()
            raise
    raise AssertionError("unreachable")  # pragma: no cover


@contextlib.contextmanager
def _transaction(path: Path, create: bool = True) -> Iterator[sqlite3.Connection]:
    """One write transaction, the tables created if absent; rolled back on any error."""
    con = _begin(path, create)
    try:
        _create(con, path)
        yield con
        con.execute("COMMIT")
    except BaseException:
        with contextlib.suppress(sqlite3.Error):
            con.execute("ROLLBACK")
        raise
    finally:
        con.close()


def _num(v: Any) -> float | None:
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) and \
        math.isfinite(v) else None


def _int(v: Any) -> int | None:
    return int(v) if isinstance(v, int) and not isinstance(v, bool) else None


def _folder_time(name: str) -> str | None:
    """The start time in a run folder's name (``20260102T030405_123456Z_seq``)."""
    try:
        t = datetime.strptime(name[:23], "%Y%m%dT%H%M%S_%fZ").replace(tzinfo=timezone.utc)
    except ValueError:
        return None
    return utc_stamp(t)


def row_of(summary: Mapping[str, Any], run_dir: str,
           meta: Mapping[str, Any] | None = None) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The store's rows for one run: from its ``summary.json`` (``dut`` and ``record``),
    for a run from before them from its ``meta.json`` (``drive``, ``sequence``,
    ``created_utc``) and folder name. Raises ValueError for a document that is not a
    run summary."""
    if not isinstance(summary, Mapping) or not isinstance(summary.get("sequence"), str):
        raise ValueError("not a run summary (no 'sequence')")
    meta = meta if isinstance(meta, Mapping) else {}
    rec = summary.get("record") if isinstance(summary.get("record"), Mapping) else {}
    dut = summary.get("dut") if isinstance(summary.get("dut"), Mapping) else {}
    if not dut and isinstance(meta.get("drive"), Mapping):  # a run from before the record
        dut = dut_fields(meta["drive"], {"drive": summary.get("drive", "unknown"),
                                         "board": summary.get("board", "")})
    mseq = meta.get("sequence") if isinstance(meta.get("sequence"), Mapping) else {}
    exps = summary.get("expectations") if isinstance(summary.get("expectations"), list) else []
    verdict = rec.get("verdict")
    if verdict not in VERDICTS:
        verdict = ("aborted" if summary.get("aborted") else
                   "passed" if summary.get("passed") is True else "failed")
    started = (rec.get("started_utc") or _folder_time(run_dir)
               or str(meta.get("created_utc") or ""))
    if not started:
        raise ValueError("no start time (no record, folder name or meta.json)")
    if not rec.get("started_utc"):  # meta's ISO time with +00:00 -> the store's form
        with contextlib.suppress(ValueError):
            started = utc_stamp(parse_when(started))
    failed = [e for e in exps if isinstance(e, Mapping)
              and (e.get("status") or ("pass" if e.get("passed") else "fail")) == "fail"]
    params = rec.get("params")
    row = {
        "run_dir": run_dir, "sequence": summary["sequence"],
        "sequence_file": rec.get("sequence_file") or mseq.get("file"),
        "sequence_sha256": rec.get("sequence_sha256"),
        "params": json.dumps(params, sort_keys=True) if isinstance(params, Mapping) else None,
        "motor": rec.get("motor") or mseq.get("motor"),
        "vendor_id": _int(dut.get("vendor_id")), "product_code": _int(dut.get("product_code")),
        "revision": _int(dut.get("revision")), "serial": _int(dut.get("serial")),
        "firmware_version": dut.get("firmware_version"), "build_id": dut.get("build_id"),
        "device_name": dut.get("device_name"),
        "drive_kind": str(summary.get("drive") or dut.get("kind") or "unknown"),
        "board": summary.get("board") or dut.get("board"),
        "fallback": int(bool(summary.get("fallback"))),
        "operator": rec.get("operator"), "station": rec.get("station"),
        "fixture": rec.get("fixture"), "started_utc": started,
        "finished_utc": rec.get("finished_utc"), "duration_s": _num(rec.get("duration_s")),
        "verdict": verdict,
        "exit_reason": rec.get("exit_reason") or summary.get("error") or None,
        "exit_code": _int(rec.get("exit_code")), "n_expectations": len(exps),
        "n_failed": len(failed), "bench_version": rec.get("bench_version")
        or meta.get("bench_version"), "recorded_utc": utc_stamp(),
    }
    erows = []
    for e in exps:
        if not isinstance(e, Mapping):
            continue
        w = e.get("window_s") if isinstance(e.get("window_s"), list) else [None, None]
        status = e.get("status") or ("pass" if e.get("passed") else "fail")
        erows.append({"name": e.get("name"), "metric": e.get("metric"),
                      "measured": _num(e.get("measured")), "criterion": e.get("criterion"),
                      "status": status, "window_t0_s": _num(w[0]) if w else None,
                      "window_t1_s": _num(w[1]) if len(w) > 1 else None,
                      "message": e.get("message"), "paper": _num(e.get("paper"))})
    return row, erows


def _insert(con: sqlite3.Connection, row: Mapping[str, Any],
            erows: list[Mapping[str, Any]]) -> int:
    con.execute("DELETE FROM runs WHERE run_dir = ?", (row["run_dir"],))  # a re-recorded run
    cols = [c for c, _ in RUN_COLUMNS]
    cur = con.execute(f"INSERT INTO runs ({', '.join(cols)}) VALUES "
                      f"({', '.join('?' for _ in cols)})", [row.get(c) for c in cols])
    run_id = int(cur.lastrowid or 0)
    ecols = [c for c, _ in EXPECT_COLUMNS]
    con.executemany(f"INSERT INTO expectations (run_id, idx, {', '.join(ecols)}) VALUES "
                    f"(?, ?, {', '.join('?' for _ in ecols)})",
                    [[run_id, i] + [e.get(c) for c in ecols] for i, e in enumerate(erows)])
    return run_id


def record_run(runs_root: str | Path, run_dir: str | Path, summary: Mapping[str, Any],
               meta: Mapping[str, Any] | None = None) -> int:
    """Add (or replace) one run's rows in the store of ``runs_root``, in one
    transaction; returns the run's row id. Raises sqlite3.Error, OSError or
    :class:`StoreError` when the store cannot be written."""
    row, erows = row_of(summary, Path(run_dir).name, meta)
    path = store_path(runs_root)
    with _transaction(path) as con:
        return _insert(con, row, erows)


def rebuild(runs_root: str | Path) -> tuple[int, list[str], Path | None]:
    """Re-create the store of ``runs_root`` from its run folders' ``summary.json``.

    Returns ``(runs recorded, skipped folders with why, where a store that could not be
    read was moved)``. All in one transaction: a run recorded meanwhile by another bench
    process waits for it (its folder is read again by the next rebuild, if it came too
    late for this one).
    """
    root = Path(runs_root)
    if not root.is_dir():
        raise FileNotFoundError(str(root))
    path = store_path(root)
    moved = None
    try:
        with _transaction(path):
            pass
    except (sqlite3.DatabaseError, StoreError) as e:
        if _busy(e):
            raise
        stamp = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%SZ")
        moved = path.with_name(f"{path.name}.unreadable-{stamp}")
        for suffix in ("", "-wal", "-shm"):
            p = Path(str(path) + suffix)
            if p.exists():
                os.replace(p, Path(str(moved) + suffix))
    rows = []
    skipped = []
    for d in sorted(p for p in root.iterdir() if p.is_dir()):
        f = d / "summary.json"
        if not f.is_file():
            continue
        try:
            summary = json.loads(f.read_text(encoding="utf-8"))
            try:
                meta = json.loads((d / "meta.json").read_text(encoding="utf-8"))
            except (OSError, ValueError):
                meta = {}
            rows.append(row_of(summary, d.name, meta))
        except (OSError, ValueError, TypeError, KeyError) as e:
            skipped.append(f"{d.name}: {' '.join(str(e).split())}")
    with _transaction(path) as con:
        con.execute("DELETE FROM expectations")
        con.execute("DELETE FROM runs")
        for row, erows in rows:
            _insert(con, row, erows)
    return len(rows), skipped, moved


# ---- queries ---------------------------------------------------------------------------


def parse_when(text: str, end: bool = False) -> datetime:
    """A date or time given to ``--since`` / ``--until``: ``2026-01-02`` (the day:
    from 00:00, or with ``end`` through its end), ``2026-01-02T10:30[:00]`` or with a
    space, UTC unless it has an offset (``Z``, ``+02:00``). Raises ValueError."""
    s = text.strip()
    try:
        if len(s) == 10:
            d = datetime.strptime(s, "%Y-%m-%d").replace(tzinfo=timezone.utc)
            return d + timedelta(days=1) - timedelta(microseconds=1) if end else d
        t = datetime.fromisoformat(s[:-1] + "+00:00" if s.endswith(("Z", "z")) else s)
    except ValueError:
        raise ValueError(f"{text!r}: not a date; give YYYY-MM-DD or YYYY-MM-DDTHH:MM[:SS] "
                         "(UTC unless an offset such as +02:00 is given)") from None
    return t.replace(tzinfo=timezone.utc) if t.tzinfo is None else t.astimezone(timezone.utc)


def parse_serial(text: str) -> int:
    """A serial number given to ``--serial``: decimal or 0x-hex. Raises ValueError."""
    s = text.strip()
    try:
        v = int(s, 16) if s.lower().startswith("0x") else int(s, 10)
    except ValueError:
        raise ValueError(f"{text!r}: not a serial number; give it as the drive reports it "
                         "(0x1018:4), decimal or 0x-hex") from None
    if not 0 <= v <= 0xFFFFFFFF:
        raise ValueError(f"{text!r}: outside 0..0xFFFFFFFF (0x1018:4 is 32 bits)")
    return v


def query(runs_root: str | Path, motor: str | None = None, serial: int | None = None,
          sequence: str | None = None, since: datetime | None = None,
          until: datetime | None = None, verdict: str | None = None,
          limit: int | None = None, expectations: bool = False) -> list[dict[str, Any]]:
    """Runs in the store of ``runs_root``, newest first, filtered (``until``
    inclusive). Raises :class:`StoreError` for a missing, corrupt or foreign store."""
    path = store_path(runs_root)
    where, args = [], []
    for col, v in (("motor", motor), ("serial", serial), ("sequence", sequence),
                   ("verdict", verdict)):
        if v is not None:
            where.append(f"{col} = ?")
            args.append(v)
    if since is not None:
        where.append("started_utc >= ?")
        args.append(utc_stamp(since))
    if until is not None:
        where.append("started_utc <= ?")
        args.append(utc_stamp(until))
    sql = ("SELECT * FROM runs" + (" WHERE " + " AND ".join(where) if where else "")
           + " ORDER BY started_utc DESC, id DESC" + (f" LIMIT {int(limit)}" if limit else ""))
    try:
        con = _connect(path, create=False)
    except sqlite3.DatabaseError as e:
        raise StoreError(_unreadable(path, e)) from None
    try:
        con.row_factory = sqlite3.Row
        _check_tables(con, path)
        rows = [dict(r) for r in con.execute(sql, args)]
        if expectations:
            for r in rows:
                r["expectations"] = [
                    {k: e[k] for k in e.keys() if k not in ("run_id", "idx")}
                    for e in con.execute("SELECT * FROM expectations WHERE run_id = ? "
                                         "ORDER BY idx", (r["id"],))]
        for r in rows:
            r["params"] = json.loads(r["params"]) if r.get("params") else None
        return rows
    except sqlite3.DatabaseError as e:
        raise StoreError(_unreadable(path, e)) from None
    finally:
        con.close()


def _unreadable(path: Path, e: BaseException) -> str:
    return (f"{path}: cannot be read as a results store ({' '.join(str(e).split())}); "
            "'bench results --rebuild' re-creates it from the run folders")


# ---- output ------------------------------------------------------------------------------

#: the table's columns: (heading, function of a row)
def _serial_text(r: Mapping[str, Any]) -> str:
    return "-" if r.get("serial") is None else str(r["serial"])


_TABLE: tuple[tuple[str, Callable[[Mapping[str, Any]], str]], ...] = (
    ("STARTED (UTC)", lambda r: str(r["started_utc"])[:19].replace("T", " ")),
    ("VERDICT", lambda r: str(r["verdict"]).upper()),
    ("SEQUENCE", lambda r: str(r["sequence"])),
    ("MOTOR", lambda r: str(r.get("motor") or "-")),
    ("DRIVE", lambda r: str(r.get("drive_kind") or "-")),
    ("SERIAL", _serial_text),
    ("FIRMWARE", lambda r: " ".join(x for x in (r.get("firmware_version"),
                                                 r.get("build_id")) if x) or "-"),
    ("OPERATOR", lambda r: str(r.get("operator") or "-")),
    ("STATION", lambda r: str(r.get("station") or "-")),
    ("FIXTURE", lambda r: str(r.get("fixture") or "-")),
    ("EXPECT", lambda r: f"{(r.get('n_expectations') or 0) - (r.get('n_failed') or 0)}/"
                         f"{r.get('n_expectations') or 0}"),
    ("TIME", lambda r: "-" if r.get("duration_s") is None else f"{r['duration_s']:.1f} s"),
    ("RUN", lambda r: str(r["run_dir"])),
)


def _cell(text: str, width: int = 40) -> str:
    text = " ".join(text.split())
    return text if len(text) <= width else text[:width - 3] + "..."


def table(rows: list[Mapping[str, Any]]) -> str:
    """A readable table (newest first as given) and a count line."""
    cells = [[h for h, _ in _TABLE]] + [[_cell(f(r), 48 if h == "RUN" else 24)
                                          for h, f in _TABLE] for r in rows]
    widths = [max(len(c[i]) for c in cells) for i in range(len(_TABLE))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)).rstrip()
             for row in cells]
    n = {v: sum(1 for r in rows if r["verdict"] == v) for v in VERDICTS}
    lines.append(f"{len(rows)} run{'s' if len(rows) != 1 else ''}: {n['passed']} passed, "
                 f"{n['failed']} failed, {n['aborted']} aborted")
    return "\n".join(lines)


def to_csv(rows: list[Mapping[str, Any]]) -> str:
    """One CSV row per run, every column of the store's runs table."""
    buf = io.StringIO()
    cols = ["id"] + [c for c, _ in RUN_COLUMNS]
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    for r in rows:
        w.writerow(["" if r.get(c) is None else
                    (json.dumps(r[c], sort_keys=True) if isinstance(r[c], dict) else r[c])
                    for c in cols])
    return buf.getvalue()


def to_json(rows: list[Mapping[str, Any]]) -> str:
    """The runs (with their expectations when queried with them) as a JSON list."""
    return json.dumps(list(rows), indent=2) + "\n"
