"""The Cortex-M4 cycle models of benchmarks/bench_cm4_estimate.py against the
timings the Cortex-M4 TRM (r0p1, 3.3.2 "Load/store timings") states for its own
examples, and the trace walker against a hand-made execution log. Pure Python:
no toolchain needed."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def cm4():
    spec = importlib.util.spec_from_file_location(
        "bench_cm4_estimate", ROOT / "benchmarks" / "bench_cm4_estimate.py")
    mod = importlib.util.module_from_spec(spec)
    assert spec.loader is not None
    spec.loader.exec_module(mod)
    return mod


def trm_total(cm4, seq: list[tuple[str, str]]) -> int:
    t = cm4.TrmTiming()
    return sum(t.cost(mn, ops) for mn, ops in seq)


@pytest.mark.parametrize(("seq", "cycles"), [
    # the TRM's own examples ("normally three/four cycles total")
    ([("ldr", "r0, [r1]"), ("ldr", "r1, [r2]")], 3),
    ([("ldr", "r0, [r1, r2]"), ("str", "r0, [r3, #20]")], 3),
    ([("ldr", "r0, [r1, r2]"), ("str", "r1, [r3, r2]")], 3),
    ([("ldr", "r0, [r1, r5]"), ("ldr", "r1, [r2]"), ("ldr", "r2, [r3, #4]")], 4),
    # "STR Rx,[Ry,#imm] is always one cycle" (2 behind another store: write buffer)
    ([("str", "r0, [r1, #4]")], 1),
    ([("str", "r0, [r1, #4]"), ("str.w", "r2, [r1, #8]")], 3),
    # a register-offset store is not pipelined behind a data-processing instruction
    ([("adds", "r0, #1"), ("str", "r0, [r3, r2]")], 3),
    # "LDR Rx,[PC,#imm] might add a cycle"; an LDR whose address the previous LDR
    # loaded is not pipelined (and is charged the stall)
    ([("ldr", "r0, [pc, #12]")], 3),
    ([("ldr", "r3, [r0]"), ("ldr", "r2, [r3, #4]")], 5),
    # "a load or store that generates an address dependent on the result of a
    # preceding data processing operation stalls ... an additional cycle"
    ([("add.w", "r3, r3, #4"), ("ldr", "r0, [r3]")], 4),
    ([("add.w", "r3, r3, #4"), ("ldr", "r0, [r4]")], 3),
    ([("sub", "sp, #8"), ("vstr", "s0, [sp]")], 4),
    # VLDR/VSTR: 2, never pipelined (the TRM does not say they are); literal +1
    ([("vldr", "s0, [r0]"), ("vldr", "s1, [r0, #4]")], 4),
    ([("vldr", "s15, [pc, #64]")], 3),
    # multiple transfers 1 + N, LDRD 3, FP multiply-accumulate 3, divide 14
    ([("vpush", "{s16-s31}")], 17),
    ([("ldrd", "r2, r3, [r0, #8]")], 3),
    ([("vfma.f32", "s0, s1, s2"), ("vdiv.f32", "s0, s1, s2")], 17),
    # the TRM's ranges at their top: IT not folded, SDIV 12
    ([("ite", "gt"), ("movgt", "r0, #1"), ("movle", "r0, #2")], 3),
    ([("sdiv", "r0, r1, r2")], 12),
])
def test_trm_model_matches_the_trm(cm4, seq, cycles) -> None:
    assert trm_total(cm4, seq) == cycles


def test_reset_forgets_the_previous_instruction(cm4) -> None:
    t = cm4.TrmTiming()
    t.cost("add.w", "r3, r3, #4")
    t.reset()  # a gap in the trace: no stall carried over
    assert t.cost("ldr", "r0, [r3]") == 2


def test_parse_trace_three_models_on_a_hand_made_log(cm4, tmp_path: Path) -> None:
    """One call of the entry: add, taken branch, literal load, two loads, return.
    Low/high/trm computed by hand from the models' rules."""
    insns = {
        0x100: (2, "adds", "r3, #1"),
        0x102: (2, "b.n", "108"),
        0x108: (2, "ldr", "r0, [pc, #8]"),
        0x10a: (2, "ldr", "r1, [r3]"),
        0x10c: (2, "ldr", "r2, [r4]"),
        0x10e: (2, "bx", "lr"),
    }
    syms = [(0x100, 0x20, "fw_step"), (0x200, 0x20, "replay_batch")]
    pcs = [0x100, 0x102, 0x108, 0x10a, 0x10c, 0x10e, 0x200]
    log = tmp_path / "exec.log"
    log.write_text("".join(f"Trace 0: 0x0 [00000000/{pc:08x}/00000000/00000000] f\n"
                           for pc in pcs))
    (n, lo, hi, trm, flow, nbytes, *_rest) = cm4.parse_trace(log, insns, syms, 1, 1, "step")
    assert n == [6] and flow == [2] and nbytes == [12]
    # low: adds 1, b 1, ldr 2, ldr 1 (pipelined), ldr 1, bx 1 = 7, + 2 refills x 1
    assert lo == [9]
    # high: 1 + 1 + 2 + 2 + 2 + 1 = 9, + 2 refills x 3
    assert hi == [15]
    # trm: adds 1, b 1, literal ldr 3, ldr [r3] 1 (pipelined; r3 came from the adds,
    # but not directly before it: no stall), ldr [r4] 1, bx 1 = 8, + 2 refills x 3
    assert trm == [14]


def test_kinds_count_both_interrupts_of_a_period(cm4) -> None:
    """--isr counts the control and the supervision interrupt, each from its own
    entry back to the harness loop that runs them one after the other."""
    assert cm4.KINDS["isr"] == ("fw_app_isr", "replay_isr_batch", "count_isr")
    assert cm4.KINDS["sup"] == ("fw_app_supervise", "replay_isr_batch", "count_sup")
    assert cm4.KINDS["bg"][1:] == ("replay_isr_batch", "count_bg")
    harness = (ROOT / "benchmarks" / "cm4" / "harness.c").read_text()
    for _entry, _caller, mode in cm4.KINDS.values():
        assert f'"{mode}"' in harness


def test_period_totals(cm4) -> None:
    """Per period: control interrupt + its entry/exit + the tail-chained supervision
    interrupt (+ one background pass), per model; low without lazy FP stacking."""
    def res(lo, hi, trm):
        return {"cycles_low_median": lo, "cycles_high_median": hi, "cycles_trm_median": trm}
    ctl, sup, bg = res(1100, 1300, 1310), res(340, 450, 430), res(1000, 1300, 1290)
    t = cm4.period_totals(ctl, sup)
    isr, chain = cm4.ISR_OVERHEAD, cm4.SUP_OVERHEAD
    assert chain == (6, 6)  # ARM's tail-chaining latency, no second FP stacking
    assert t["low"]["total"] == 1100 + 340 + isr[0] + chain[0]
    assert t["high"]["total"] == 1300 + 450 + isr[1] + chain[1]
    assert t["trm"]["total"] == 1310 + 430 + isr[1] + chain[1]
    assert t["high"]["background"] == 0.0
    assert t["high"]["share"] == pytest.approx(100 * t["high"]["total"] / cm4.BUDGET)
    tb = cm4.period_totals(ctl, sup, bg)
    for model, extra in (("low", 1000), ("high", 1300), ("trm", 1290)):
        assert tb[model]["total"] == t[model]["total"] + extra
