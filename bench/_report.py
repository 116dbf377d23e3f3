"""Run reports: HTML with matplotlib PNG plots, JUnit XML, summary JSON."""

from __future__ import annotations

import html
import json
import math
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np

from bench._runner import RunResult
from bench._units import MotorUnits
from sim_fallback.metrics import METRIC_DEFS, definitions_rows, wrap_pi


def _clean(x: Any) -> Any:
    """NaN/inf -> None so the JSON stays valid."""
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, (np.floating, np.integer)):
        return _clean(x.item())
    return x


def summary(result: RunResult, extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """The ``--summary-json`` document: ``{"sequence", "passed", "metrics", ...}``.

    Metrics that cannot be computed (no truth) are ``null``; ``metric_windows_s``
    gives the window each headline metric covers (definitions:
    :mod:`sim_fallback.metrics`).
    """
    doc: dict[str, Any] = {
        "sequence": result.sequence,
        "passed": bool(result.passed),
        "metrics": _clean(dict(result.metrics)),
        "metric_windows_s": _clean({k: list(w) for k, w in result.metric_windows.items()}),
        "expectations": [_clean({"name": e.name, "metric": e.metric, "measured": e.measured,
                                 "criterion": e.criterion, "window_s": list(e.window_s),
                                 "passed": e.passed, "paper": e.paper,
                                 "paper_reproduced": e.paper_met})
                         for e in result.expectations],
        "aborted": result.aborted,
        "error": result.error,
        "safe_state": result.safe_state,
    }
    if extra:
        doc.update(_clean(extra))
    return doc


def write_summary_json(path: str | Path, result: RunResult,
                       extra: dict[str, Any] | None = None) -> None:
    """Write :func:`summary` to ``path``."""
    Path(path).write_text(json.dumps(summary(result, extra), indent=2) + "\n")


def write_junit(path: str | Path, results: list[RunResult],
                drive: dict[str, Any] | None = None) -> None:
    """JUnit XML: one testsuite per sequence, one testcase per expectation.

    A sequence that aborted (exception, Ctrl-C) or could not reach the safe
    state gets an ``<error>`` testcase named ``run``. ``drive`` (from
    ``bench._session.drive_kind``) becomes testsuite properties ``drive``
    (SIMULATED / HARDWARE), ``simulated`` and ``fallback``, so that a CI job
    can tell a simulated pass from a hardware pass.
    """
    suites = ET.Element("testsuites")
    for r in results:
        suite_props = None
        if drive:
            suite_props = ET.Element("properties")
            for k in ("drive", "simulated", "fallback"):
                v = drive.get(k)
                ET.SubElement(suite_props, "property", name=k,
                              value=str(v).lower() if isinstance(v, bool) else str(v))
        cases = []
        for e in r.expectations:
            tc = ET.Element("testcase", classname=f"bench.{r.sequence}", name=e.name,
                            time="0")
            if not e.passed:
                f = ET.SubElement(tc, "failure", message=e.message or "failed",
                                  type="ExpectationFailed")
                f.text = (f"{e.metric} over {list(e.window_s)} s: measured {e.measured!r}, "
                          f"required {e.criterion} (sequence line {e.line})")
            if e.paper is not None:
                props = ET.SubElement(tc, "properties")
                ET.SubElement(props, "property", name="paper", value=f"{e.paper:g}")
                ET.SubElement(props, "property", name="paper_reproduced",
                              value=str(bool(e.paper_met)).lower())
            cases.append(tc)
        run = ET.Element("testcase", classname=f"bench.{r.sequence}", name="run",
                         time=f"{r.wall_s:.3f}")
        if r.aborted or r.safe_state != "disabled":
            err = ET.SubElement(run, "error", message=r.error or r.safe_state,
                                type="RunAborted")
            err.text = f"error: {r.error}\nsafe state: {r.safe_state}"
        cases.append(run)
        n_fail = sum(1 for c in cases if c.find("failure") is not None)
        n_err = sum(1 for c in cases if c.find("error") is not None)
        suite = ET.SubElement(suites, "testsuite", name=r.sequence, tests=str(len(cases)),
                              failures=str(n_fail), errors=str(n_err),
                              time=f"{r.wall_s:.3f}")
        if suite_props is not None:
            suite.append(suite_props)
        suite.extend(cases)
    ET.indent(suites)
    ET.ElementTree(suites).write(path, encoding="utf-8", xml_declaration=True)


# ---- plots ----------------------------------------------------------------------------


def _decimate(t: np.ndarray, v: np.ndarray, n_max: int = 6000
              ) -> tuple[np.ndarray, np.ndarray]:
    if t.size <= n_max:
        return t, v
    k = int(math.ceil(t.size / n_max))
    return t[::k], v[::k]


def make_plots(logger: Any, result: RunResult, units: MotorUnits, out_dir: Path
               ) -> list[tuple[str, str]]:
    """PNG plots of a run; returns ``[(file name, caption), ...]``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t0 = logger.t_origin_s
    rpm = 60.0 / (2.0 * math.pi * units.pole_pairs)  # electrical rad/s -> r/min

    def ch(name: str) -> tuple[np.ndarray, np.ndarray]:
        t, v = logger.channel(name)
        return t - t0, v

    plots: list[tuple[str, str]] = []
    truth = logger.truth()

    def shade(ax: Any) -> None:
        for e in result.expectations:
            ax.axvspan(*e.window_s, color="tab:green" if e.passed else "tab:red", alpha=0.06)
        for w in logger.windows:
            ax.axvspan(w["t0_s"], w["t1_s"], color="tab:purple", alpha=0.08)

    if truth is not None:
        t = truth["t_s"]
        fig, axs = plt.subplots(4, 1, figsize=(10, 11), sharex=True)
        a, b = _decimate(t, wrap_pi(truth["theta_e_rad"]))
        axs[0].plot(a, b, lw=0.8, label="true theta_e")
        a, b = _decimate(t, wrap_pi(truth["theta_hat_rad"]))
        axs[0].plot(a, b, lw=0.8, ls="--", label="estimate theta_hat")
        axs[0].set_ylabel("electrical angle (rad)")
        axs[0].legend(loc="upper right")
        err = wrap_pi(truth["theta_e_rad"] - truth["theta_hat_rad"])
        a, b = _decimate(t, err)
        axs[1].plot(a, b, lw=0.6, color="tab:red")
        axs[1].set_ylabel("position error (rad el.)")
        lim = max(0.05, float(np.nanpercentile(np.abs(err[t > 0.1]), 99.5)) * 1.3) \
            if np.any(t > 0.1) else 0.2
        axs[1].set_ylim(-lim, lim)
        a, b = _decimate(t, truth["omega_e_radps"] * rpm)
        axs[2].plot(a, b, lw=0.8, label="true speed")
        a, b = _decimate(t, truth["omega_hat_radps"] * rpm)
        axs[2].plot(a, b, lw=0.8, ls="--", label="estimated speed")
        ts, vs = ch("sim.speed_ref_radps_e")
        if ts.size:
            a, b = _decimate(ts, vs * rpm)
            axs[2].plot(a, b, lw=0.8, color="k", alpha=0.5, label="reference")
        axs[2].set_ylabel("speed (r/min)")
        axs[2].legend(loc="upper right")
        tl, vl = ch("sim.load_N")
        if tl.size:
            a, b = _decimate(tl, vl * units.radius_m)
            axs[3].plot(a, b, lw=0.8, color="tab:brown", label="load (N·m equiv.)")
        tf, vf = ch("sim.force_N")
        if tf.size:
            a, b = _decimate(tf, vf * units.radius_m)
            axs[3].plot(a, b, lw=0.5, alpha=0.7, label="thrust (N·m equiv.)")
        axs[3].set_ylabel("N·m (rotary equiv.)")
        axs[3].set_xlabel("sequence time (s)")
        axs[3].legend(loc="upper right")
        for ax in axs:
            shade(ax)
            ax.grid(alpha=0.3)
        fig.suptitle(f"{result.sequence}: truth vs estimate")
        fig.tight_layout()
        fig.savefig(out_dir / "overview.png", dpi=90)
        plt.close(fig)
        plots.append(("overview.png", "true vs estimated position and speed, position error, "
                                      "load; shaded: expectation windows (green pass, red "
                                      "fail), trace captures (purple)"))

    # estimator internals
    names = [("sim.i_dq_hat_A", "i_d / i_q (A)"), ("sim.pll_err_rad", "PLL error (rad)"),
             ("sim.hf_amp_A", "HF amplitude (A)"), ("sim.sogi_k_eff", "SOGI k")]
    have = [(n, lbl) for n, lbl in names if logger.channel(n)[0].size]
    if have:
        fig, axs = plt.subplots(len(have), 1, figsize=(10, 2.4 * len(have)), sharex=True,
                                squeeze=False)
        for ax, (n, lbl) in zip(axs[:, 0], have, strict=True):
            t, v = ch(n)
            if v.ndim > 1:
                for j, lab in enumerate(("i_d", "i_q")[: v.shape[1]]):
                    a, b = _decimate(t, v[:, j])
                    ax.plot(a, b, lw=0.6, label=lab)
                ax.legend(loc="upper right")
            else:
                a, b = _decimate(t, v)
                ax.plot(a, b, lw=0.6)
            ax.set_ylabel(lbl)
            ax.grid(alpha=0.3)
            shade(ax)
        axs[-1, 0].set_xlabel("sequence time (s)")
        fig.tight_layout()
        fig.savefig(out_dir / "estimator.png", dpi=90)
        plt.close(fig)
        plots.append(("estimator.png", "firmware internals (from the simulated drive's record)"))

    # what came over the wire (TPDOs)
    wanted = ("pdo.statusword", "pdo.speed_hat_mps", "pdo.pos_hat_m", "pdo.force_hat_N",
              "pdo.error_code", "pdo.theta_hat_rad")
    have_ch = logger.channels()
    pdo = [(n, have_ch[n]) for n in wanted if n in have_ch]
    if pdo:
        fig, axs = plt.subplots(len(pdo), 1, figsize=(10, 1.8 * len(pdo)), sharex=True,
                                squeeze=False)
        for ax, (n, u) in zip(axs[:, 0], pdo, strict=True):
            t, v = ch(n)
            a, b = _decimate(t, v)
            ax.step(a, b, where="post", lw=0.7)
            ax.set_ylabel(f"{n[4:]}\n({u})" if u else n[4:], fontsize=8)
            ax.grid(alpha=0.3)
        axs[-1, 0].set_xlabel("sequence time (s)")
        fig.tight_layout()
        fig.savefig(out_dir / "pdo.png", dpi=80)
        plt.close(fig)
        plots.append(("pdo.png", "signals decoded from the drive's TPDOs (what the bench "
                                 "receives over CAN)"))

    # trace captures at full rate
    for w in logger.windows:
        sigs = w["signals"] or ["theta_hat_rad", "pll_err_rad"]
        drv = f"trace.{w['name']}."
        rows = [s for s in sigs if logger.channel("sim." + s)[0].size
                or logger.channel(drv + s)[0].size]
        if not rows:
            continue
        fig, axs = plt.subplots(len(rows), 1, figsize=(10, 2.0 * len(rows)), sharex=True,
                                squeeze=False)
        for ax, s in zip(axs[:, 0], rows, strict=True):
            t, v = ch("sim." + s)
            m = (t >= w["t0_s"]) & (t <= w["t1_s"])
            if t.size:
                ax.plot(t[m], v[m], lw=0.7, label="simulator record")
            t, v = ch(drv + s)
            if t.size:
                ax.plot(t, v, lw=0.7, ls="--", label="drive trace buffer (serial upload)")
            ax.legend(loc="upper right", fontsize=7)
            ax.set_ylabel(s, fontsize=8)
            ax.grid(alpha=0.3)
        axs[-1, 0].set_xlabel("sequence time (s)")
        fig.suptitle(f"trace capture '{w['name']}' (full control rate)")
        fig.tight_layout()
        fname = f"trace_{w['name']}.png"
        fig.savefig(out_dir / fname, dpi=90)
        plt.close(fig)
        plots.append((fname, f"trace capture {w['name']}: {w['t0_s']:.3f}-{w['t1_s']:.3f} s"))
    return plots


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return "n/a" if not math.isfinite(v) else f"{v:.5g}"
    return html.escape(str(v))


def _sim_banner(meta: dict[str, Any]) -> str:
    """A banner that no reader can miss when the drive was simulated."""
    info = meta.get("connection_info") or {}
    if info.get("kind") != "sim":
        return ""
    why = ("FALLBACK: no drive hardware answered, the bench used the simulated drive. "
           if info.get("fallback") else "")
    return ('<p class="simbanner">SIMULATED DRIVE &mdash; ' + why +
            "These results come from the simulator (plant + firmware), not from hardware. "
            "Use --require-hardware to make a missing rig an error.</p>")


def _sim_suffix(meta: dict[str, Any]) -> str:
    info = meta.get("connection_info") or {}
    return " (SIMULATED drive)" if info.get("kind") == "sim" else ""


def write_html(path: Path, result: RunResult, plots: list[tuple[str, str]],
               meta: dict[str, Any], logstats: dict[str, Any]) -> None:
    """Self-contained HTML report (PNG files next to it)."""
    ok = result.passed
    rows = "\n".join(
        f"<tr class='{'pass' if e.passed else 'fail'}'><td>{_fmt(e.name)}</td>"
        f"<td>{_fmt(e.metric)}</td><td>[{e.window_s[0]:g}, {e.window_s[1]:g}]</td>"
        f"<td>{_fmt(e.measured)}</td><td>{_fmt(e.criterion)}</td>"
        f"<td>{'PASS' if e.passed else 'FAIL'}</td>"
        f"<td>{'' if e.paper is None else _fmt(e.paper)}</td>"
        f"<td>{'' if e.paper_met is None else ('yes' if e.paper_met else 'NO')}</td>"
        f"<td>{_fmt(e.message)}</td></tr>"
        for e in result.expectations)
    def win(k: str) -> str:
        w = result.metric_windows.get(k)
        return "" if w is None else f"[{w[0]:g}, {w[1]:g}]"

    metrics = "\n".join(
        f"<tr><td>{_fmt(k)}</td><td>{_fmt(v)}</td>"
        f"<td>{_fmt(METRIC_DEFS[k].unit if k in METRIC_DEFS else '')}</td><td>{win(k)}</td></tr>"
        for k, v in result.metrics.items())
    defs = definitions_rows()
    defs_html = ("<tr>" + "".join(f"<th>{html.escape(c)}</th>" for c in defs[0]) + "</tr>\n"
                 + "\n".join("<tr>" + "".join(f"<td>{html.escape(v)}</td>" for v in r.values())
                              + "</tr>" for r in defs))
    figs = "\n".join(f"<figure><img src='{html.escape(f)}' alt='{html.escape(c)}'>"
                     f"<figcaption>{html.escape(c)}</figcaption></figure>" for f, c in plots)
    drive = meta.get("drive", {})
    info = "\n".join(f"<tr><td>{_fmt(k)}</td><td>{_fmt(v)}</td></tr>" for k, v in {
        "connection": meta.get("connection"), "firmware": drive.get("firmware_version"),
        "build id": drive.get("build_id"), "motor": meta.get("sequence", {}).get("motor"),
        "extractor": meta.get("sequence", {}).get("extractor"),
        "seed": meta.get("sequence", {}).get("seed"), "bench": meta.get("bench_version"),
        "CAN frames logged": logstats.get("frames_logged"),
        "lost frames": logstats.get("lost_frames"),
        "receive-thread errors": len(logstats.get("receive_errors", [])),
        "safe state": result.safe_state, "error": result.error,
        "sequence time (s)": result.duration_s, "wall time (s)": result.wall_s}.items())
    doc = f"""<!doctype html>
<html><head><meta charset="utf-8"><title>{html.escape(result.sequence)} - bench report</title>
<style>
body {{ font-family: sans-serif; margin: 2em; max-width: 1100px; }}
table {{ border-collapse: collapse; margin: 1em 0; }}
td, th {{ border: 1px solid #ccc; padding: 3px 8px; font-size: 14px; }}
tr.pass td:nth-child(6) {{ color: #070; font-weight: bold; }}
tr.fail td {{ background: #fee; }} tr.fail td:nth-child(6) {{ color: #b00; font-weight: bold; }}
.verdict {{ font-size: 1.4em; font-weight: bold; color: {'#070' if ok else '#b00'}; }}
img {{ max-width: 100%; }} figcaption {{ color: #555; font-size: 13px; }}
.simbanner {{ background: #ffe08a; border: 3px solid #c80; padding: 0.6em 1em;
  font-weight: bold; font-size: 1.1em; }}
</style></head><body>
<h1>{html.escape(result.sequence)}</h1>
{_sim_banner(meta)}
<p class="verdict">{'PASSED' if ok else 'FAILED'}{_sim_suffix(meta)}</p>
<p>{html.escape(str(meta.get('sequence', {}).get('description', '')))}</p>
<h2>Expectations</h2>
<table><tr><th>expectation</th><th>metric</th><th>window (s)</th><th>measured</th>
<th>required</th><th>result</th><th>paper</th><th>paper reproduced</th><th>note</th></tr>
{rows}
</table>
<h2>Metrics over their default windows</h2>
<table><tr><th>metric</th><th>value</th><th>unit</th><th>window (s)</th></tr>
{metrics}</table>
<h2>Metric definitions</h2>
<table>{defs_html}</table>
<h2>Run</h2>
<table>{info}</table>
<h2>Plots</h2>
{figs}
</body></html>
"""
    path.write_text(doc, encoding="utf-8")
