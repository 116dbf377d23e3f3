"""The recording of ``bench live --sim --rerun save X.rrd`` read back with rerun's own reader
(``rerun.chunk.RrdReader``): every signal decoded from the wire (and the simulated drive's
truth) is in the .rrd with the documented number of samples and the decoded values, and the
views (blueprint: layout, legend names, colours) are in the ``X.rbl`` beside it, which the
printed command passes to the viewer.

The reference is independent of bench._live: every item the drive's threads handed to
``LiveFeed.put`` is copied (a wrapper around it), then mapped to entities with the table of
docs/bench.md, converted with numpy (``np.angle(exp(1j x))`` for the wrap, the motor's pole
pairs and pole pitch for r/min) and decimated as documented (the first sample of each 20 ms;
steps: every change, the old value repeated at the change, plus 5 rows/s). Tolerances: time
2 ns (int64 ns timeline), values 1e-12 relative + 1e-12 absolute (the same float64
arithmetic in another order); steps exact.
"""

from __future__ import annotations

import shlex
import sys
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests" / "python"))

from sim_libs import needs_sim  # noqa: E402

import bench._live as live  # noqa: E402
from bench._live import read_rrd  # noqa: E402

RATE_HZ = 50.0
STEP_HZ = 5.0

# decoded signal -> (entity, conversion): the table of docs/bench.md, written out here
WIRE = {
    "tel.theta_hat_rad": ("position/estimate", "wrap"),
    "tel.omega_hat_radps": ("speed/estimate", "rpm"),
    "tel.omega_f_radps": ("speed/estimate_filtered", "rpm"),
    "tel.speed_ref_radps_e": ("speed/reference", "rpm"),
    "tel.pll_err_rad": ("pll/error", None),
    "tel.pll_err_f_rad": ("pll/error_filtered", None),
    "tel.hf_amp_A": ("hf/amplitude", None),
    "tel.hf_q_A": ("hf/q", None),
    "tel.i_d_A": ("current/i_d", None),
    "tel.i_q_A": ("current/i_q", None),
    "tel.i_d_ref_A": ("current/i_d_ref", None),
    "tel.i_q_ref_A": ("current/i_q_ref", None),
    "tel.force_hat_N": ("force/estimate_tel", None),
    "pdo.pos_hat_m": ("position_m/estimate", None),
    "pdo.speed_hat_mps": ("speed/pdo", "mps_rpm"),
    "pdo.force_hat_N": ("force/estimate", None),
}
STEPS = {
    "tel.statusword": "state/statusword_tel", "tel.fault_code": "state/fault_code",
    "tel.start_phase": "state/start_phase", "pdo.statusword": "state/statusword",
    "pdo.mode_display": "state/mode", "pdo.error_code": "state/error_code",
    "pdo.error_register": "state/error_register", "pdo.start_phase": "state/start_phase_pdo",
}
# the default truth set: entity <- simulator channel (conversion)
TRUTH = {"truth/position": ("theta_e_rad", "wrap"), "truth/speed": ("omega_e_radps", "rpm"),
         "truth/load": ("load_N", None)}

VIEWS = ["position (rad el.): estimate vs truth", "position error (rad el.)",
         "speed (r/min): estimates, reference, truth", "currents (A)",
         "force (N): estimate, load", "position (m)", "PLL error (rad), HF amplitude (A)",
         "drive state", "other wire signals"]


def _wrap(x: np.ndarray) -> np.ndarray:
    return np.angle(np.exp(1j * x))


def _concat(items: list[tuple[Any, Any]]) -> tuple[np.ndarray, np.ndarray]:
    t = np.concatenate([np.atleast_1d(np.asarray(a, np.float64)) for a, _ in items])
    v = np.concatenate([np.atleast_1d(np.asarray(b, np.float64)) for _, b in items])
    o = np.argsort(t, kind="stable")
    return t[o], v[o]


def _first_per_interval(t: np.ndarray) -> np.ndarray:
    _, idx = np.unique(np.floor(t * RATE_HZ), return_index=True)
    return idx


def _blueprint_rows(rbl: Path) -> dict[str, list[Any]]:
    """Component name -> every value logged in a blueprint file (rerun's reader)."""
    from rerun.chunk import RrdReader

    out: dict[str, list[Any]] = {}
    reader = RrdReader(rbl)
    assert len(reader.blueprints()) == 1 and not reader.recordings()
    for ch in reader.stream(store=reader.blueprints()[0]):
        rb = ch.to_record_batch()
        for name in rb.schema.names:
            for x in rb.column(name).to_pylist():
                out.setdefault(name, []).append(x)
    return out


@needs_sim
def test_recording_holds_every_decoded_signal_and_the_views_are_beside_it(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
        ) -> None:
    from bench._units import motor_units
    from bench.cli import main

    seen: list[tuple[str, Any, dict[str, Any]]] = []
    lock = threading.Lock()
    put = live.LiveFeed.put

    def tee(self: Any, prefix: str, t: Any, values: dict[str, Any]) -> bool:
        with lock:
            seen.append((prefix, np.array(t, np.float64, copy=True),
                         {k: np.array(v, np.float64, copy=True) for k, v in values.items()}))
        return put(self, prefix, t, values)

    monkeypatch.setattr(live.LiveFeed, "put", tee)
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    out = tmp_path / "x.rrd"
    rc = main(["live", "--sim", "--duration", "2", "--rerun", "save", str(out)])
    err = capsys.readouterr().err
    assert rc == 0, err
    assert " 0 dropped" in err, err

    # the printed command opens the recording with its blueprint
    rbl = tmp_path / "x.rbl"
    cmd = err.split("; view: ", 1)[1].splitlines()[0]
    assert shlex.split(cmd) == ["rerun", str(out), str(rbl)], cmd

    units = motor_units("paper_salient")
    rpm = 60.0 / (2.0 * np.pi * units.pole_pairs)        # rad/s el. -> r/min
    mps_rpm = 60.0 / (2.0 * np.pi * units.pole_pairs * units.pole_pitch_m / np.pi)
    conv = {None: lambda x: x, "wrap": _wrap, "rpm": lambda x: x * rpm,
            "mps_rpm": lambda x: x * mps_rpm}

    by_key: dict[str, list[tuple[Any, Any]]] = {}
    for prefix, t, values in seen:
        for k, v in values.items():
            by_key.setdefault(prefix + k, []).append((t, v))
    cont: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    steps: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for key, items in by_key.items():
        t, v = _concat(items)
        if key in WIRE:
            entity, c = WIRE[key]
            cont[entity] = (t, conv[c](v))
        elif key in STEPS:
            steps[STEPS[key]] = (t, v)
        elif not key.startswith("sim."):
            cont[key.replace(".", "/", 1)] = (t, v)
    for entity, (ch, c) in TRUTH.items():
        cont[entity] = (lambda tv: (tv[0], conv[c](tv[1])))(_concat(by_key["sim." + ch]))
    ts, te = _concat(by_key["sim.theta_e_rad"])
    _, th = _concat(by_key["sim.theta_hat_rad"])
    cont["truth/position_error"] = (ts, _wrap(te - th))

    # what the simulated drive's wire carries by default, at least (docs/bench.md)
    assert {"position/estimate", "speed/estimate", "speed/pdo", "position_m/estimate",
            "force/estimate", "current/i_q", "hf/amplitude", "truth/position",
            "truth/speed", "truth/position_error", "truth/load"} <= set(cont), sorted(cont)
    assert {"state/statusword", "state/mode", "state/error_code"} <= set(steps)

    got = read_rrd(out)
    assert set(got) == set(cont) | set(steps), (sorted(got), sorted(cont), sorted(steps))
    for entity, (t, v) in cont.items():
        idx = _first_per_interval(t)
        tg, vg = got[entity]
        assert tg.size == idx.size, (entity, tg.size, idx.size)
        np.testing.assert_allclose(tg, t[idx], rtol=0, atol=2e-9, err_msg=entity)
        np.testing.assert_allclose(vg, v[idx], rtol=1e-12, atol=1e-12, err_msg=entity)
    for entity, (t, v) in steps.items():
        tg, vg = got[entity]
        # sample-and-hold of the recording gives back every decoded sample
        held = vg[np.searchsorted(tg, t + 1e-9, side="right") - 1]
        np.testing.assert_array_equal(held, v, err_msg=entity)
        changes = 1 + int(np.count_nonzero(v[1:] != v[:-1]))
        assert tg.size <= 2 * changes + STEP_HZ * (t[-1] - t[0]) + 2, (entity, tg.size)

    # the .rrd holds the recording only; the views are the blueprint file beside it
    from rerun.chunk import RrdReader

    reader = RrdReader(out)
    assert len(reader.recordings()) == 1 and not reader.blueprints()
    bp = _blueprint_rows(rbl)
    names = [x[0] if isinstance(x, list) else x for x in bp["ViewBlueprint:display_name"]]
    assert sorted(names) == sorted(VIEWS), names
    legend = {n for x in bp.get("SeriesLines:names", []) for n in (x or [])}
    assert {label for label, _ in live._STYLE.values()} == legend
    queries = {q for x in bp["ViewContents:query"] for q in (x or [])}
    for entity in set(got):  # every recorded entity is in one of the views ("+ /a/**")
        assert any(entity == q[3:].removesuffix("/**") or
                   (q.endswith("/**") and entity.startswith(q[3:-2])) for q in queries), entity
