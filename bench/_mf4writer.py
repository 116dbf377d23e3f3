"""The MF4 writer as a child process: asammdf's import (about 0.7 s of CPU: pandas,
sympy, canmatrix) and the compression of the signals run on another core, beside
the run, instead of holding the bench's interpreter lock while the simulated drive
and the CAN threads need it.

The bench sends write jobs (pickled, over the child's stdin) as the run produces
them: the crash-safety parts every ``flush_s`` and the joined ``signals.mf4`` at the
end. The child reads every job as soon as it arrives (so the bench never waits for
the import), writes them in order with :func:`bench._logging._write_mf4` (the one MF4
writer) and reports each result as one JSON line on stdout. When the bench dies the
child still writes every job it received, then exits (its stdin is closed).

When the child cannot be started, dies, or reports a failed job, :class:`Mf4Writer`
writes that job in the bench's own process: nothing recorded is lost.

Run as ``python -m bench._mf4writer`` (only by :class:`Mf4Writer`).
"""

from __future__ import annotations

import atexit
import json
import logging
import os
import pickle
import queue
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

log = logging.getLogger("bench.logging")

Job = dict[str, Any]


def _do(job: Job) -> None:
    from bench._logging import _write_mf4

    path = Path(job["path"])
    _write_mf4(path, job["rows"], header=job.get("header"),
               compression=int(job.get("compression", 0)))
    parts = job.get("remove_parts")
    if parts:
        d = Path(parts)
        for p in d.glob("part_*.mf4"):
            p.unlink()
        try:
            d.rmdir()
        except OSError:
            pass


class Mf4Writer:
    """Writes MF4 jobs in a child process, in order; falls back to this process.

    One child serves every run of a bench process (:meth:`shared`), so that asammdf is
    imported once, and early: ``bench run`` starts it before its own imports.

    Parameters
    ----------
    use_process : bool
        False writes every job here, synchronously (for tests, and for an interpreter
        that cannot start itself).
    """

    _shared: Mf4Writer | None = None

    def __init__(self, use_process: bool = True) -> None:
        self._proc: subprocess.Popen[bytes] | None = None
        self._jobs: dict[int, Job] = {}   # sent, not yet confirmed written
        self._retry: list[Job] = []       # reported failed by the child: written here
        self._n = 0
        self._cond = threading.Condition()
        self._child_gone = False
        self.failed: list[str] = []       # files that could not be written at all
        self.fallbacks = 0                # jobs written in this process instead
        self._wanted_process = use_process
        if use_process:
            self._start()

    @classmethod
    def shared(cls) -> Mf4Writer:
        """The bench process's writer (started on first use, stopped at exit)."""
        if cls._shared is None or cls._shared._proc is None:
            cls._shared = cls(use_process=True)
            atexit.register(cls._shared.shutdown)
        return cls._shared

    @classmethod
    def running(cls) -> bool:
        """Whether the shared writer process is up (started early by ``bench run``)."""
        return cls._shared is not None and cls._shared._proc is not None

    def _start(self) -> None:
        env = dict(os.environ)
        root = str(Path(__file__).resolve().parents[1])
        env["PYTHONPATH"] = os.pathsep.join([root] + ([env["PYTHONPATH"]]
                                                      if env.get("PYTHONPATH") else []))
        try:
            self._proc = subprocess.Popen(
                [sys.executable, "-m", "bench._mf4writer"], stdin=subprocess.PIPE,
                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, env=env,
                start_new_session=True)  # a Ctrl-C for the bench must not kill the writer
        except OSError as e:
            log.warning("MF4 writer process not started (%s): writing in the bench", e)
            self._proc = None
            return
        threading.Thread(target=self._read_results, args=(self._proc,),
                         name="bench-mf4-results", daemon=True).start()

    def _read_results(self, proc: subprocess.Popen[bytes]) -> None:
        """Drop each job (its arrays) as the child confirms it written."""
        assert proc.stdout is not None
        for line in proc.stdout:
            try:
                r = json.loads(line)
            except ValueError:
                continue
            with self._cond:
                job = self._jobs.pop(r.get("id"), None)
                if job is not None and not r.get("ok"):
                    log.warning("MF4 writer process: %s", r.get("error"))
                    self._retry.append(job)
                self._cond.notify_all()
        with self._cond:
            self._child_gone = True
            self._cond.notify_all()

    def write(self, path: Path, rows: list[tuple[str, str, Any, Any]],
              header: dict[str, str] | None = None, compression: int = 0,
              remove_parts: Path | None = None) -> None:
        """Queue one file (written in order after the jobs before it)."""
        job: Job = {"path": str(path), "rows": rows, "header": header,
                    "compression": compression,
                    "remove_parts": str(remove_parts) if remove_parts else None}
        with self._cond:
            if self._proc is not None and not self._child_gone:
                self._n += 1
                job["id"] = self._n
                self._jobs[self._n] = job
                try:
                    assert self._proc.stdin is not None
                    pickle.dump(job, self._proc.stdin, protocol=pickle.HIGHEST_PROTOCOL)
                    self._proc.stdin.flush()
                    return
                except (OSError, ValueError) as e:
                    log.warning("MF4 writer process lost (%s): writing in the bench", e)
                    self._child_gone = True
                    self._jobs.pop(self._n, None)
        self.sync()  # in order: what the child did not confirm first, then this one
        if self._wanted_process:
            self.fallbacks += 1
        self._here(job)

    def _here(self, job: Job) -> None:
        try:
            _do(job)
        except Exception as e:  # noqa: BLE001 - reported in the run's log statistics
            self.failed.append(f"{Path(job['path']).name}: {type(e).__name__}: {e}")
            log.error("could not write %s: %s", job["path"], e)

    def sync(self, timeout_s: float = 120.0) -> None:
        """Return when every file queued so far is written (by the child, else here)."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while self._jobs and not self._child_gone:
                left = deadline - time.monotonic()
                if left <= 0:
                    log.warning("MF4 writer process: no answer in %.0f s: writing in the "
                                "bench", timeout_s)
                    self._kill()
                    break
                self._cond.wait(min(left, 0.5))
                if self._proc is not None and self._proc.poll() is not None:
                    self._child_gone = True
            todo = self._retry + [self._jobs[k] for k in sorted(self._jobs)]
            self._retry, self._jobs = [], {}
        if todo:
            todo.sort(key=lambda j: j.get("id", 0))
        for job in todo:
            self.fallbacks += 1
            self._here(job)

    def _kill(self) -> None:
        self._child_gone = True
        if self._proc is not None:
            try:
                self._proc.kill()
            except OSError:
                pass

    def shutdown(self, timeout_s: float = 120.0) -> None:
        """Write everything queued, then let the child exit (not waited for: every
        file is confirmed written, and its interpreter teardown takes 0.2 s)."""
        self.sync(timeout_s)
        proc, self._proc = self._proc, None
        if proc is None:
            return
        try:
            assert proc.stdin is not None
            proc.stdin.close()
        except OSError:
            pass


def _child() -> int:
    """The child: read jobs as they come (a reader thread), write them in order."""
    jobs: queue.Queue[Job | None] = queue.Queue()
    stdin = sys.stdin.buffer
    out = sys.stdout

    def reader() -> None:
        try:
            while True:
                jobs.put(pickle.load(stdin))
        except (EOFError, OSError, pickle.UnpicklingError):
            pass
        finally:
            jobs.put(None)

    # what unpickling a job needs is imported before the reader thread starts: numpy
    # imported by both threads at once fails now and then ("partially initialized")
    import numpy  # noqa: F401

    threading.Thread(target=reader, name="mf4-jobs", daemon=True).start()
    # sympy is optional for asammdf (algebraic conversions, which these files do not
    # use) and a quarter of its import time
    sys.modules.setdefault("sympy", None)  # type: ignore[arg-type]
    import asammdf  # noqa: F401 - the slow import, while the jobs arrive

    while (job := jobs.get()) is not None:
        try:
            _do(job)
            res = {"id": job.get("id"), "ok": True}
        except Exception as e:  # noqa: BLE001 - reported to the bench, which retries
            res = {"id": job.get("id"), "ok": False, "error": f"{type(e).__name__}: {e}"}
        try:
            out.write(json.dumps(res) + "\n")
            out.flush()
        except OSError:
            pass  # the bench is gone: keep writing what was received
    return 0


if __name__ == "__main__":
    sys.exit(_child())
