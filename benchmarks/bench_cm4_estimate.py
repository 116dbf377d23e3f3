#!/usr/bin/env python3
"""Cost of one fw_step() (and of the drive's interrupts) on a Cortex-M4F, from
instructions counted under QEMU.

What it does
  1. Cross-compiles the firmware core (firmware_c/src/*.c) with the real
     target flags (-mcpu=cortex-m4 -mthumb -mfpu=fpv4-sp-d16 -mfloat-abi=hard)
     plus the harness in benchmarks/cm4/ into a bare-metal image for QEMU's
     mps2-an386 board (a Cortex-M4F), once per optimisation level (-O2 and
     -Os by default; -Os is what the project's MinSizeRel CM4 image uses, with
     the control path's sources at -O2 as that image compiles them:
     firmware_c/CMakeLists.txt, PMLSM_CM4_FAST_SOURCES / PMLSM_CM4_FAST_OPT,
     read from there), with link-time optimisation (-flto) as the CM4 image is
     built (one object per source, then the LTO link); --no-lto measures
     separate translation units.
  2. Runs it once untraced ("warm"): the locked-mover plant of
     benchmarks/bench_fw_step.c drives the core into closed-loop RUN (0.2 s +
     24 000 samples, same as the host benchmark); the controller state and
     the recorded inputs are written to a host file through semihosting.
  3. Runs it again ("count") under `-d exec,nochain` with one instruction
     per translation block, replaying BATCH x NB recorded inputs, each batch
     from a copy of the saved state (as bench_fw_step.c does; batches are
     whole injection periods so the controller stays locked). Every
     instruction executed from fw_step's first instruction until control is
     back in the harness is counted, callees included; the harness checks
     that the controller is still in RUN without a fault after every batch.
     --isr measures the drive application's two interrupts of a period the
     same way (harness modes count_isr and count_sup: per period the control
     interrupt fw_app_isr, then the supervision interrupt fw_app_supervise
     it pends, as the board runs them), --bg its background loop
     (count_bg), and the per-period totals.
  4. Classifies each executed instruction from the image's disassembly and
     converts the counts to cycles with a low and a high Cortex-M4 cost
     model (see CYCLE MODEL below), then prints instructions/step (median
     over batches), the cycle range, the share of the 7083-cycle budget
     (170 MHz / 24 kHz) and the margin to the 50 % target.

Needs: arm-none-eabi-gcc + newlib (Debian: gcc-arm-none-eabi,
libnewlib-arm-none-eabi) and qemu-system-arm (Debian: qemu-system-arm).
Exits 2 with a message when they are missing, 1 when a step fails (build
error, warm-up not reaching RUN, controller leaving RUN during the replay),
3 when the sources changed during the run. Outputs go to benchmarks/out/cm4/.

Usage: python3 benchmarks/bench_cm4_estimate.py [--opt O2,Os] [--batch 80]
       [--batches 10] [--no-lto] [--isr] [--bg] [--by-source] [--json out.json]
       [--keep-log]

CYCLE MODEL (Cortex-M4 TRM r0p1 table 3-1, FPv4-SP table 7-1; zero-wait-
state instruction fetch, i.e. code in CCM SRAM or always hitting the
flash accelerator):
  - data processing, MUL, SMULL/UMULL/SMLAL/UMLAL, most FP (VADD, VSUB,
    VMUL, VNMUL, VABS, VNEG, VCMP, VCVT, VMOV, VMRS/VMSR): 1
  - MLA/MLS: 2; SDIV/UDIV: 2 (low) .. 12 (high)
  - VMLA/VMLS/VNMLA/VNMLS/VFMA/VFMS/VFNMA/VFNMS: 3; VMOV of 2 core regs: 2
  - VDIV, VSQRT: 14
  - single load/store (LDR*, STR*, VLDR, VSTR): 2 (high); 1 (low) when it
    directly follows another single load/store (address/data pipelining)
  - LDRD/STRD: 3; LDM/STM/PUSH/POP/VLDM/VSTM/VPUSH/VPOP: 1 + N words
  - every change of flow (taken branch, BL, BX, POP {pc}, ...): + P pipeline
    refill cycles, P = 1 (low) .. 3 (high); TBB/TBH: +1 more
  - IT: 0 (low, folded) .. 1 (high)
  A third model, 'trm', applies the TRM's own sequence rules instead of the
  two bounds above (class TrmTiming): single integer LDR 2, or 1 when it
  directly follows an LDR whose result is not its address; STR with an
  immediate offset 1 (2 right after another store); literal-pool loads +1;
  a load/store whose address the instruction before it computed +1;
  VLDR/VSTR 2 (the TRM does not say they pipeline); P = 3, IT 1, SDIV 12. It
  is a cross-check of the high model, which ignores both the pipelining the
  TRM grants and the stalls it charges (in SPEED mode the two agree within
  1 %: the control interrupt's loads and stores are mostly VLDR/VSTR).
  Not in the model: flash wait states on misses of the flash accelerator
  (reported separately as a cold-flash fetch bound: executed code bytes / 8
  plus one line per change of flow, times 1 + 4 wait states),
  interrupt entry/exit (~12 + ~10 cycles, + ~17 + ~17 with lazy FP
  stacking; added to the budget line; the supervision interrupt is
  tail-chained to the control interrupt: + 6, see SUP_OVERHEAD), bus
  contention with DMA.
"""

from __future__ import annotations

import argparse
import bisect
import functools
import hashlib
import json
import re
import shutil
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FW = ROOT / "firmware_c"
CM4 = ROOT / "benchmarks" / "cm4"
OUT = ROOT / "benchmarks" / "out" / "cm4"

F_CPU_HZ = 170e6
F_ISR_HZ = 24e3
BUDGET = F_CPU_HZ / F_ISR_HZ  # 7083.3 cycles
TARGET_SHARE = 0.50
ISR_OVERHEAD = (22, 56)  # entry + exit cycles, without / with lazy FP context stacking
# The supervision interrupt (fw_app_supervise) is pended by the control interrupt at a
# lower priority than it and higher than the background (fw_board.h), so the core
# tail-chains into it when the control interrupt returns: no exit + entry (10 + 12)
# between the two, but the ARM tail-chaining latency of 6 cycles instead (Cortex-M4 TRM
# r0p1 5.5.1 / ARM's interrupt latency figures: 12 entry, 6 tail-chaining). The stacked
# context (with its lazily stacked FP registers, which the control interrupt's FP code
# has already saved) is kept across the chain, so no FP stacking again; the one exit (10,
# + 17 FP unstacking) at the end of the supervision interrupt is the one ISR_OVERHEAD
# already charges to the control interrupt. Per period: ISR_OVERHEAD + SUP_OVERHEAD.
SUP_OVERHEAD = (6, 6)  # tail-chaining, without / with lazy FP context stacking
ISR_TARGET = 1500  # issue 13: the control interrupt's median cycles per step (21 % of a period)
FLASH_WS = 4  # flash wait states of an STM32G4-class part at 170 MHz

CPU_FLAGS = ["-mcpu=cortex-m4", "-mthumb", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard"]
TOOLS = ["arm-none-eabi-gcc", "arm-none-eabi-objdump", "arm-none-eabi-nm",
         "arm-none-eabi-addr2line", "qemu-system-arm"]
INSTALL_HINT = (
    "install them with: apt-get update && apt-get install -y gcc-arm-none-eabi "
    "libnewlib-arm-none-eabi qemu-system-arm"
)


def die(msg: str, code: int = 1) -> None:
    print(f"bench_cm4_estimate: {msg}", file=sys.stderr)
    sys.exit(code)


def run(cmd: list[str], **kw) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, capture_output=True, text=True, **kw)


def check_tools() -> None:
    missing = [t for t in TOOLS if shutil.which(t) is None]
    if missing:
        die(f"missing tools: {', '.join(missing)}; {INSTALL_HINT}", 2)
    # newlib's semihosting crt0 for the hard-float v7e-m multilib
    r = run(["arm-none-eabi-gcc", *CPU_FLAGS, "-print-file-name=rdimon-crt0.o"])
    if r.returncode != 0 or not Path(r.stdout.strip()).is_file():
        die(f"newlib (rdimon-crt0.o) not found for {' '.join(CPU_FLAGS)}; {INSTALL_HINT}", 2)
    r = run(["qemu-system-arm", "-M", "help"])
    if "mps2-an386" not in r.stdout:
        die("qemu-system-arm has no mps2-an386 machine (need QEMU >= 6.0)", 2)


def qemu_version() -> tuple[int, int]:
    r = run(["qemu-system-arm", "--version"])
    m = re.search(r"version (\d+)\.(\d+)", r.stdout)
    return (int(m.group(1)), int(m.group(2))) if m else (0, 0)


def one_insn_per_tb_args() -> list[str]:
    # -singlestep was renamed to -accel tcg,one-insn-per-tb=on in QEMU 8.1
    return ["-accel", "tcg,one-insn-per-tb=on"] if qemu_version() >= (8, 1) else ["-singlestep"]


def source_fingerprint() -> str:
    """sha256 (12 hex) over the core's sources and headers and the harness."""
    h = hashlib.sha256()
    files = [*(FW / "src").glob("*.c"), *(FW / "include").rglob("*.h"), *CM4.glob("*"),
             *(FW / "comm" / "src").glob("*.c"), *(FW / "comm" / "include").rglob("*.h")]
    for p in sorted(files):
        if p.is_file():
            h.update(p.name.encode())
            h.update(p.read_bytes())
    return h.hexdigest()[:12]


def harness_sources() -> tuple[list[str], list[str]]:
    """Sources and include flags of the harness (M4 image and host build alike): the
    core, and the drive application around it for the control interrupt (fw_app_isr;
    the rest of the application is dropped by --gc-sections)."""
    srcs = sorted(str(p) for p in (FW / "src").glob("*.c"))
    srcs += sorted(str(p) for p in (FW / "comm" / "src").glob("*.c")
                   if p.name != "fw_board.c")  # the board glue needs a port: not here
    srcs += sorted(str(p) for p in (FW / "comm" / "generated").glob("*.c"))
    srcs.append(str(CM4 / "harness.c"))
    incs = [f"-I{FW / 'include'}", f"-I{FW / 'comm' / 'include'}",
            f"-I{FW / 'comm' / 'generated'}"]
    return srcs, incs


def speed_sources(opt: str) -> dict[str, str]:
    """The sources the CM4 image compiles at another level than its build type's
    (firmware_c/CMakeLists.txt: PMLSM_CM4_FAST_SOURCES, at PMLSM_CM4_FAST_OPT),
    by absolute path; only for -Os (MinSizeRel, the shipped image)."""
    if opt != "Os":
        return {}
    text = (FW / "CMakeLists.txt").read_text()
    m = re.search(r"set\(PMLSM_CM4_FAST_SOURCES([^)]*)\)", text)
    lvl = re.search(r"set\(PMLSM_CM4_FAST_OPT\s+-(O\w+)\)", text)
    if not m or not lvl:
        return {}
    out = {}
    for tok in m.group(1).split():
        name = tok.replace("${CMAKE_CURRENT_SOURCE_DIR}/", "")
        out[str((FW / name).resolve())] = lvl.group(1)
    return out


def build(opt: str, outdir: Path, lto: bool = True) -> Path:
    outdir.mkdir(parents=True, exist_ok=True)
    elf = outdir / "harness.elf"
    srcs, incs = harness_sources()
    common = [
        *CPU_FLAGS,
        *(["-flto"] if lto else []),  # as the CM4 image: inlining across the blocks
        "-std=c11",
        "-DNDEBUG",
        "-ffunction-sections",
        "-fdata-sections",
        "-Wall",
        "-Wextra",
        "-g",
        *incs,
    ]
    # one object per source, each at the level the CM4 image compiles it at
    # (speed_sources), then one link (with -flto, every function keeps the
    # level it was compiled at)
    fast = speed_sources(opt)
    objs = []
    for i, src in enumerate([*srcs, str(CM4 / "startup.c")]):
        obj = outdir / f"{i:02d}_{Path(src).stem}.o"
        lvl = fast.get(str(Path(src).resolve()), opt)
        r = run(["arm-none-eabi-gcc", f"-{lvl}", *common, "-c", src, "-o", str(obj)])
        if r.returncode != 0:
            die(f"cross build (-{lvl}, {src}) failed:\n{r.stderr}")
        objs.append(str(obj))
    cmd = [
        "arm-none-eabi-gcc",
        f"-{opt}",
        *common,
        *objs,
        "-T",
        str(CM4 / "cm4.ld"),
        "--specs=nano.specs",
        "--specs=rdimon.specs",
        "-Wl,--gc-sections",
        f"-Wl,-Map={outdir / 'harness.map'}",
        "-lm",
        "-o",
        str(elf),
    ]
    r = run(cmd)
    if r.returncode != 0:
        die(f"cross build (-{opt}) failed:\n{r.stderr}")
    return elf


def qemu(
    elf: Path, args: list[str], extra: list[str], timeout: float, cwd: Path | None = None
) -> subprocess.CompletedProcess:
    """Runs the image; args go to its main() through semihosting (whose command
    line is short: newlib's rdimon takes ~255 characters, so long host paths are
    better given relative to cwd, the directory QEMU runs in)."""
    # QEMU option syntax: a literal comma inside a value is written ",,"
    semi = "enable=on,target=native," + ",".join(
        "arg=" + a.replace(",", ",,") for a in ["harness", *args]
    )
    cmd = [
        "qemu-system-arm",
        "-M",
        "mps2-an386",
        "-nographic",
        "-monitor",
        "none",
        "-serial",
        "none",
        "-kernel",
        str(elf),
        "-semihosting-config",
        semi,
        *extra,
    ]
    try:
        return run(cmd, timeout=timeout, cwd=cwd)
    except subprocess.TimeoutExpired:
        die(f"qemu timed out: {' '.join(cmd)}")
    raise AssertionError


def symbols(elf: Path) -> list[tuple[int, int, str]]:
    r = run(["arm-none-eabi-nm", "-S", "--defined-only", str(elf)])
    out = []
    for line in r.stdout.splitlines():
        p = line.split()
        if len(p) == 4 and p[2] in "tTwW":
            out.append((int(p[0], 16), int(p[1], 16), p[3]))
    return sorted(out)


INSN_RE = re.compile(r"^\s*([0-9a-f]+):\s+((?:[0-9a-f]{4}\s?){1,2})\s+(\S+)\s*(.*)$")


def disassemble(elf: Path) -> dict[int, tuple[int, str, str]]:
    r2 = run(["arm-none-eabi-objdump", "-d", str(elf)])
    insns: dict[int, tuple[int, str, str]] = {}
    for line in r2.stdout.splitlines():
        m = INSN_RE.match(line)
        if not m:
            continue
        addr = int(m.group(1), 16)
        size = 2 * len(m.group(2).split())
        insns[addr] = (size, m.group(3).lower(), m.group(4).split("@")[0].strip().lower())
    return insns


COND = tuple(("eq ne cs cc hs lo mi pl vs vc hi ls ge lt gt le al").split())


@functools.cache
def base_mnemonic(mn: str) -> str:
    mn = mn.split(".")[0]  # drop .w/.n/.f32
    if mn in KNOWN_BASES or mn in V_BASES:
        return mn
    for c in COND:  # conditional forms inside IT blocks, e.g. movlt, ldrne, vldrmi
        if mn.endswith(c) and len(mn) > len(c):
            b = mn[: -len(c)]
            if b in KNOWN_BASES or b in V_BASES:
                return b
    return mn


KNOWN_BASES = set(
    (
        "mov movs mvn mvns add adds sub subs rsb rsbs and ands orr orrs eor eors bic bics cmp "
        "cmn tst teq lsl lsls lsr lsrs asr asrs ldr ldrb ldrh ldrsb ldrsh ldrd str strb strh "
        "strd b bl bx blx pop push ldm ldmia stm stmia mul muls mla mls sdiv udiv ubfx sbfx "
        "uxtb uxth sxtb sxth movw movt clz ssat usat bfi bfc orn adc sbc addw subw tbb tbh "
        "cbz cbnz ldrex strex smull umull smlal umlal nop ror rors neg negs"
    ).split()
)

V_BASES = set(
    (
        "vldr vstr vldm vldmia vldmdb vstm vstmia vstmdb vpush vpop vmov vmrs vmsr vadd vsub "
        "vmul vnmul vdiv vsqrt vabs vneg vcmp vcmpe vcvt vcvtr vmla vmls vnmla vnmls vfma "
        "vfms vfnma vfnms"
    ).split()
)

SINGLE_LS = set(("ldr ldrb ldrh ldrsb ldrsh ldrex ldrt str strb strh strex vldr vstr").split())
MULTI = set(
    (
        "ldm ldmia ldmfd ldmdb stm stmia stmea stmdb stmfd push pop vldm vldmia vldmdb vstm "
        "vstmia vstmdb vpush vpop"
    ).split()
)
FP_MAC = {"vmla", "vmls", "vnmla", "vnmls", "vfma", "vfms", "vfnma", "vfnms"}


def reg_words(ops: str) -> int:
    """Number of 32-bit words moved by a register-list instruction."""
    m = re.search(r"\{([^}]*)\}", ops)
    if not m:
        return 1
    n = 0
    for part in m.group(1).split(","):
        part = part.strip()
        if not part:
            continue
        w = 2 if part.startswith("d") else 1
        if "-" in part:
            a, b = part.split("-")
            n += (int(re.sub(r"\D", "", b)) - int(re.sub(r"\D", "", a)) + 1) * w
        else:
            n += w
    return n


@functools.cache
def classify(mn: str, ops: str) -> tuple[str, int, int, bool]:
    """-> (class, low cycles, high cycles, pipelinable single load/store);
    pipeline refill after a change of flow is added by the caller."""
    b = base_mnemonic(mn)
    if not b or mn.startswith("."):  # literal-pool data: never executed
        return "?", 1, 1, False
    if b in ("vdiv", "vsqrt"):
        return b, 14, 14, False
    if b in FP_MAC:
        return "fp_mac", 3, 3, False
    if b in SINGLE_LS:
        kind = "load" if b.startswith(("ldr", "vldr")) else "store"
        return kind, 2, 2, True
    if b in ("ldrd", "strd"):
        return ("load" if b == "ldrd" else "store"), 3, 3, False
    if b in MULTI:
        n = reg_words(ops)
        kind = "load" if b.startswith(("ldm", "pop", "vldm", "vpop")) else "store"
        return kind, 1 + n, 1 + n, False
    if b in ("mla", "mls"):
        return "mul", 2, 2, False
    if b in ("mul", "muls", "smull", "umull", "smlal", "umlal"):
        return "mul", 1, 1, False
    if b in ("sdiv", "udiv"):
        return "div", 2, 12, False
    if b in ("tbb", "tbh"):
        return "branch", 2, 2, False
    if b in ("b", "bl", "bx", "blx", "cbz", "cbnz"):
        return "branch", 1, 1, False
    if b == "it" or re.fullmatch(r"it[te]{0,3}", b):
        return "it", 0, 1, False
    if b == "vmov" and ops.count(",") >= 2:  # vmov r0, r1, d0 / vmov s0, s1, r0, r1
        return "fp", 2, 2, False
    if b.startswith("v"):
        return "fp", 1, 1, False
    return "alu", 1, 1, False


REG_RE = re.compile(r"\b(r1[0-5]|r[0-9]|sp|lr|pc|ip|fp|sl|sb)\b")
NO_DEST = {"cmp", "cmn", "tst", "teq", "b", "bx", "cbz", "cbnz", "tbb", "tbh", "it", "nop",
           "vcmp", "vcmpe", "vmsr"}


REG_ALIAS = {"ip": "r12", "fp": "r11", "sl": "r10", "sb": "r9"}


def _regs(text: str) -> set[str]:
    """Core registers named in an operand string (ip = r12, fp = r11, ...)."""
    return {REG_ALIAS.get(r, r) for r in REG_RE.findall(text)}


def address_regs(b: str, ops: str) -> set[str]:
    """Registers a load/store's address generation reads."""
    if b in ("push", "pop", "vpush", "vpop"):
        return {"sp"}
    m = re.search(r"\[([^\]]*)\]", ops)
    if m:
        return _regs(m.group(1))
    return _regs(ops.split(",")[0])  # ldm/stm/vldm/vstm: the base register


def written_regs(b: str, ops: str) -> set[str]:
    """Core registers an instruction writes (for the address-dependency stall)."""
    if b in NO_DEST or b in ("str", "strb", "strh", "strd", "vstr", "push", "vpush", "stm",
                             "stmia", "stmdb", "stmea", "stmfd", "vstm", "vstmia", "vstmdb"):
        out: set[str] = set()
    elif b in ("pop", "ldm", "ldmia", "ldmfd", "ldmdb"):
        m = re.search(r"\{([^}]*)\}", ops)
        out = _regs(m.group(1)) if m else set()
    elif b in ("ldrd", "smull", "umull", "smlal", "umlal", "strex"):
        out = _regs(",".join(ops.split(",")[:2]))
    elif b == "bl" or b == "blx":
        out = {"lr", "r0", "r1", "r2", "r3", "r12"}
    else:
        out = _regs(ops.split(",")[0]) if ops else set()
    if b in ("push", "pop", "vpush", "vpop"):
        out.add("sp")
    if "!" in ops or re.search(r"\],\s*#", ops):  # base writeback
        out |= address_regs(b, ops)
    return out


INT_LOAD = {"ldr", "ldrb", "ldrh", "ldrsb", "ldrsh", "ldrex", "ldrt"}
INT_STORE = {"str", "strb", "strh", "strex"}


class TrmTiming:
    """The Cortex-M4 TRM's own timing rules for a stream of instructions
    (TRM r0p1 3.3.1-3.3.2, FPv4-SP table 7-1): the 'trm' model. Where the TRM
    gives a range it takes the top (refill P = 3, IT not folded, SDIV 12); where
    it is silent it assumes no gain (VLDR/VSTR never pipelined, 2 cycles each).
      - LDR (single, integer): 2, or 1 directly after a single integer LDR whose
        result is not used to compute this address ("LDR [any] are pipelined
        when possible ... one cycle is removed from the cost of the next
        instruction")
      - STR with an immediate offset: 1 ("always one cycle"), 2 directly after
        another store (the write buffer may still hold it); STR with a register
        offset: 2, or 1 when pipelined after an LDR as above
      - LDR/VLDR from the literal pool ([pc, #imm]): +1 ("might add a cycle
        because of contention with the fetch unit")
      - any load/store whose address uses the result of the instruction just
        before it, other than a load: +1 ("no forwarding path")
      - LDRD/STRD 3 (never pipelined), LDM/STM/PUSH/POP/VLDM/VSTM 1 + N
      - the rest as the high model
    cost() is called once per executed instruction, in order; reset() after a
    gap in the stream."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.prev_b = ""
        self.prev_dest: set[str] = set()
        self.prev_store = False

    @staticmethod
    @functools.cache
    def _static(mn: str, ops: str) -> tuple:
        """What cost() needs of an instruction that does not depend on the stream
        (cached: parse_trace calls cost() once per executed instruction)."""
        b = base_mnemonic(mn)
        cls, _lo, hi, _pipe = classify(mn, ops)
        ls = cls in ("load", "store")
        addr = frozenset(address_regs(b, ops)) if ls else frozenset()
        reg_offset = bool(re.search(r"\[[^\],]+,\s*(r\d+|ip|fp|sl|sb|lr)", ops))
        return b, cls, hi, ls, addr, reg_offset, frozenset(written_regs(b, ops))

    def cost(self, mn: str, ops: str) -> int:
        b, cls, hi, ls, addr, reg_offset, dest = self._static(mn, ops)
        single = b in INT_LOAD or b in INT_STORE or b in ("vldr", "vstr")
        if ls:
            c = hi
            if single:
                after_ldr = self.prev_b in INT_LOAD and not (self.prev_dest & addr)
                if b in INT_STORE and not reg_offset:
                    c = 2 if self.prev_store else 1
                elif b in INT_LOAD or b in INT_STORE:
                    c = 1 if after_ldr else 2
                else:
                    c = 2  # vldr/vstr
                if "pc" in addr:
                    c += 1
            if self.prev_dest & addr:  # loads too (the TRM is silent: assume the stall)
                c += 1
        else:
            c = hi
        self.prev_b = b
        self.prev_dest = dest
        self.prev_store = cls == "store"
        return c


# what is counted: entry symbol and the harness function it returns to
KINDS = {
    "step": ("fw_step", "replay_batch", "count"),
    "isr": ("fw_app_isr", "replay_isr_batch", "count_isr"),
    "sup": ("fw_app_supervise", "replay_isr_batch", "count_sup"),
    "bg": ("fw_app_background", "replay_isr_batch", "count_bg"),
}


def parse_trace(log: Path, insns, syms, batch: int, nb: int, kind: str = "step"):
    """Walk the exec log; count per call from the entry of KINDS[kind] (fw_step,
    fw_app_isr, fw_app_supervise or fw_app_background) until the PC is back in the harness function
    that called it. Returns per-call insn counts and low/high cycles, per-class,
    per-function and per-PC totals."""
    by_name = {name: (a, s) for a, s, name in syms}
    entry = by_name[KINDS[kind][0]][0]
    rb_lo, rb_sz = by_name[KINDS[kind][1]]
    rb_hi = rb_lo + rb_sz
    starts = [a for a, _, _ in syms]

    def func_of(pc: int) -> str:
        i = bisect.bisect_right(starts, pc) - 1
        return syms[i][2] if i >= 0 else "?"

    steps_n, steps_lo, steps_hi, steps_flow, steps_bytes = [], [], [], [], []
    steps_trm: list[int] = []
    trm = TrmTiming()
    cls_count: dict[str, int] = {}
    fn_count: dict[str, int] = {}
    pc_count: dict[int, int] = {}
    pc_cyc: dict[int, list[int]] = {}  # pc -> [low, high, trm] cycles, refill included
    unknown = 0
    inside = False
    n = lo = hi = tc = flow = nbytes = 0
    prev = None  # (pc, size, is_single_ls)
    with open(log, errors="replace") as f:
        for line in f:
            if not line.startswith("Trace"):
                continue
            lb = line.find("[")
            fields = line[lb + 1 : line.find("]", lb)].split("/")
            pc = int(fields[1], 16)
            if inside and prev is not None and pc != prev[0] + prev[1]:
                flow += 1  # the previous instruction changed the flow
                cyc = pc_cyc[prev[0]]
                cyc[0] += 1
                cyc[1] += 3
                cyc[2] += 3
            if not inside:
                if pc == entry:
                    inside, n, lo, hi, tc, flow, nbytes, prev = True, 0, 0, 0, 0, 0, 0, None
                    trm.reset()
                else:
                    continue
            elif rb_lo <= pc < rb_hi:
                steps_n.append(n)
                steps_lo.append(lo + flow * 1)
                steps_hi.append(hi + flow * 3)
                steps_trm.append(tc + flow * 3)
                steps_flow.append(flow)
                steps_bytes.append(nbytes)
                inside = False
                continue
            ins = insns.get(pc)
            if ins is None:
                unknown += 1
                size, c, lc, hc, pipe, t = 2, "?", 1, 1, False, 1
                trm.reset()
            else:
                size = ins[0]
                c, lc, hc, pipe = classify(ins[1], ins[2])
                t = trm.cost(ins[1], ins[2])
            if pipe and prev is not None and prev[2]:
                lc = 1
            n += 1
            nbytes += size
            lo += lc
            hi += hc
            tc += t
            cls_count[c] = cls_count.get(c, 0) + 1
            pc_count[pc] = pc_count.get(pc, 0) + 1
            cyc = pc_cyc.setdefault(pc, [0, 0, 0])
            cyc[0] += lc
            cyc[1] += hc
            cyc[2] += t
            prev = (pc, size, pipe)
    for pc, k in pc_count.items():
        fn = func_of(pc)
        fn_count[fn] = fn_count.get(fn, 0) + k
    footprint = sum(insns[pc][0] if pc in insns else 2 for pc in pc_count)
    if len(steps_n) != batch * nb:
        die(f"trace holds {len(steps_n)} complete {KINDS[kind][0]} calls, "
            f"expected {batch * nb}")
    return (
        steps_n,
        steps_lo,
        steps_hi,
        steps_trm,
        steps_flow,
        steps_bytes,
        footprint,
        cls_count,
        fn_count,
        unknown,
        pc_count,
        pc_cyc,
    )


def by_source(elf: Path, pc_count: dict[int, int], pc_cyc: dict[int, list[int]],
              nsteps: int) -> list[tuple[str, float, float, float, float]]:
    """Attribute every executed instruction to the innermost (inlined) function
    of its source line (DWARF, addr2line -i): -> [(function (file), insns/step,
    low cycles/step, high cycles/step, trm cycles/step)], most high cycles first."""
    pcs = sorted(pc_count)
    r = run(["arm-none-eabi-addr2line", "-a", "-f", "-i", "-e", str(elf)],
            input="\n".join(f"0x{pc:x}" for pc in pcs))
    owner: dict[int, str] = {}
    cur = None
    lines = r.stdout.splitlines()
    i = 0
    while i < len(lines):
        ln = lines[i]
        if ln.startswith("0x"):
            cur = int(ln, 16)
            fn = lines[i + 1] if i + 1 < len(lines) else "?"
            loc = lines[i + 2] if i + 2 < len(lines) else "?"
            f = Path(loc.split(":")[0]).name
            owner[cur] = f"{fn} ({f})"
            i += 3
            while i < len(lines) and not lines[i].startswith("0x"):
                i += 1
            continue
        i += 1
    acc: dict[str, list[float]] = {}
    for pc in pcs:
        a = acc.setdefault(owner.get(pc, "?"), [0.0, 0.0, 0.0, 0.0])
        a[0] += pc_count[pc]
        a[1] += pc_cyc[pc][0]
        a[2] += pc_cyc[pc][1]
        a[3] += pc_cyc[pc][2]
    out = [(k, v[0] / nsteps, v[1] / nsteps, v[2] / nsteps, v[3] / nsteps)
           for k, v in acc.items()]
    return sorted(out, key=lambda t: -t[3])


def batch_medians(v: list[int], batch: int) -> float:
    per = [sum(v[i : i + batch]) / batch for i in range(0, len(v), batch)]
    return statistics.median(per)


def measure(opt: str, mode: str, elf: Path, batch: int, nb: int, keep_log: bool,
            kind: str = "step", source: bool = False) -> dict:
    outdir = elf.parent
    state = outdir / f"state_{mode}.bin"
    r = qemu(elf, ["warm", str(state), str(batch * nb), mode], [], timeout=600)
    if r.returncode != 0 or "warm ok" not in r.stdout:
        die(f"warm-up run (-{opt}) failed (rc {r.returncode}):\n{r.stdout}{r.stderr}")
    log = outdir / f"exec_{mode}.log"
    r = qemu(
        elf,
        [KINDS[kind][2], str(state), str(batch), str(nb)],
        [*one_insn_per_tb_args(), "-d", "exec,nochain", "-D", str(log)],
        timeout=900,
    )
    if r.returncode != 0 or "closed_loop=yes" not in r.stdout:
        die(
            f"count run (-{opt}) failed or left closed loop (rc {r.returncode}):\n"
            f"{r.stdout}{r.stderr}"
        )
    syms = symbols(elf)
    insns = disassemble(elf)
    (steps_n, steps_lo, steps_hi, steps_trm, steps_flow, steps_bytes, footprint, cls, fns,
     unknown, pc_count, pc_cyc) = parse_trace(log, insns, syms, batch, nb, kind)
    # flash fetch bound with no accelerator hits: 64-bit lines, 1 + WS cycles each,
    # one extra line per change of flow
    fetch = [(b / 8 + f) * (1 + FLASH_WS) for b, f in zip(steps_bytes, steps_flow, strict=True)]
    if not keep_log:
        log.unlink()
    total = sum(steps_n)
    res = {
        "opt": opt,
        "mode": mode + ("" if kind == "step" else "+" + kind),
        "steps": len(steps_n),
        "batch": batch,
        "batches": nb,
        "insns_per_step_median": batch_medians(steps_n, batch),
        "insns_per_step_min": min(steps_n),
        "insns_per_step_max": max(steps_n),
        "cycles_low_median": batch_medians(steps_lo, batch),
        "cycles_high_median": batch_medians(steps_hi, batch),
        "cycles_high_max_step": max(steps_hi),
        "cycles_trm_median": batch_medians(steps_trm, batch),
        "cycles_trm_max_step": max(steps_trm),
        "flow_changes_per_step": batch_medians(steps_flow, batch),
        "code_bytes_executed_per_step": batch_medians(steps_bytes, batch),
        "code_footprint_bytes": footprint,
        "cold_flash_fetch_bound_cycles": batch_medians(fetch, batch),
        "class_per_step": {k: v / len(steps_n) for k, v in sorted(cls.items())},
        "functions_per_step": {
            k: v / len(steps_n) for k, v in sorted(fns.items(), key=lambda kv: -kv[1])
        },
        "unknown_pcs": unknown,
        "total_insns": total,
    }
    if source:
        res["source_functions_per_step"] = [
            {"function": k, "insns": n, "cycles_low": lo, "cycles_high": hi, "cycles_trm": t}
            for k, n, lo, hi, t in by_source(elf, pc_count, pc_cyc, len(steps_n))
        ]
    return res


def report_by_source(res: dict) -> None:
    if "source_functions_per_step" in res:
        print("by source function, inlined code attributed to its innermost function "
              "(insns/call, cycles/call low..high, trm):")
        for e in res["source_functions_per_step"]:
            if e["cycles_high"] >= 1.0:
                print(f"  {e['function']:<52} {e['insns']:7.1f} {e['cycles_low']:7.1f} .. "
                      f"{e['cycles_high']:7.1f}  {e['cycles_trm']:7.1f}")


def report(res: dict) -> None:
    opt = res["opt"]
    lo, hi = res["cycles_low_median"], res["cycles_high_median"]
    what = {"force": "FORCE mode as bench_fw_step.c", "speed": "SPEED mode, speed loop on"}
    kind = res["mode"].partition("+")[2] or "step"
    title = {"step": "fw_step", "isr": "fw_app_isr (the control interrupt)",
             "sup": "fw_app_supervise (the supervision interrupt, tail-chained)",
             "bg": "fw_app_background (one pass of the background loop per period)"}
    ovh = SUP_OVERHEAD if kind == "sup" else ISR_OVERHEAD
    entry_exit = "tail-chaining" if kind == "sup" else "ISR entry/exit"
    print(
        f"\n== {title[kind]}"
        f" on Cortex-M4F, -{opt}, {what[res['mode'].partition('+')[0]]} "
        f"({res['steps']} closed-loop RUN steps, "
        f"{res['batches']} batches of {res['batch']}) =="
    )
    print(
        f"instructions/step: median {res['insns_per_step_median']:.1f}  "
        f"(single steps: min {res['insns_per_step_min']}, max {res['insns_per_step_max']})"
    )
    cls = res["class_per_step"]
    mix = "  ".join(f"{k} {v:.1f}" for k, v in sorted(cls.items(), key=lambda kv: -kv[1]))
    print(f"mix per step: {mix}  | changes of flow {res['flow_changes_per_step']:.1f}")
    top = list(res["functions_per_step"].items())[:8]
    print("by function (insns/step): " + ", ".join(f"{k} {v:.0f}" for k, v in top))
    worst_step = res["cycles_high_max_step"]
    if kind == "bg":
        print(
            f"estimated cycles per pass (zero-wait fetch): {lo:.0f} .. {hi:.0f}, trm "
            f"{res['cycles_trm_median']:.0f}  (worst single pass, high model: {worst_step}); "
            f"{100 * lo / BUDGET:.1f} % .. {100 * hi / BUDGET:.1f} % of a period "
            f"(worst pass {100 * worst_step / BUDGET:.1f} %)"
        )
        print(
            "rate: the background loop runs free in the main loop between interrupts "
            "(fw_board_background); it must average one pass per period "
            f"({F_ISR_HZ / 1e3:.0f} kHz) to keep the snapshot ring "
            f"(FW_APP_SNAP_RING periods) from overrunning, in the time the interrupts leave"
        )
        report_by_source(res)
        return
    print(
        f"estimated cycles/step (zero-wait fetch): {lo:.0f} .. {hi:.0f}, trm "
        f"{res['cycles_trm_median']:.0f}  (worst single step, high model: {worst_step}, trm "
        f"{res['cycles_trm_max_step']})"
    )
    print(
        f"share of the {BUDGET:.0f}-cycle budget (170 MHz / 24 kHz): "
        f"{100 * lo / BUDGET:.1f} % .. {100 * hi / BUDGET:.1f} %  "
        f"(with {entry_exit} {ovh[0]}..{ovh[1]} cycles: "
        f"{100 * (lo + ovh[0]) / BUDGET:.1f} % .. "
        f"{100 * (hi + ovh[1]) / BUDGET:.1f} %)"
    )
    if kind == "sup":
        print("the supervision interrupt is pended by the control interrupt and runs, "
              "tail-chained, before the next one (a miss latches 0x6100 "
              "SUPERVISION_MISSED): per period it adds to the control interrupt "
              "(see the per-period totals in the summary)")
        report_by_source(res)
        return
    tgt = TARGET_SHARE * BUDGET
    worst = worst_step + ISR_OVERHEAD[1]
    verdict = "MEETS" if worst <= tgt else "MISSES"
    print(
        f"margin to the 50 % target ({tgt:.0f} cycles), worst step, high model, incl. ISR "
        f"entry/exit: {tgt - worst:+.0f} cycles -> {verdict} the target; "
        f"headroom to 100 %: {BUDGET - worst:+.0f} cycles"
    )
    report_by_source(res)
    fb = res["cold_flash_fetch_bound_cycles"]
    print(
        f"caveat, code in flash: {res['code_bytes_executed_per_step']:.0f} code bytes "
        f"executed/step, "
        f"footprint {res['code_footprint_bytes']} B; if every fetch missed the flash "
        f"accelerator ({FLASH_WS} WS, 64-bit lines) fetch alone would take ~{fb:.0f} cycles "
        f"({100 * fb / BUDGET:.0f} % of budget): run the ISR path from CCM SRAM"
    )
    if res["unknown_pcs"]:
        print(f"warning: {res['unknown_pcs']} executed PCs not found in the disassembly")


def period_totals(ctl: dict, sup: dict, bg: dict | None = None) -> dict[str, dict]:
    """One period's cycles per model (median step of each): the control interrupt
    (ctl, a `+isr` result) with its entry/exit, the supervision interrupt (sup, a
    `+sup` result) with its tail-chaining, and with bg (a `+bg` result) one
    background pass. -> {"low"|"high"|"trm": {control, supervision, entry_exit,
    tail_chain, background, total, share (% of the period)}}; the low model takes
    the overheads without lazy FP stacking, high and trm with it."""
    out = {}
    for model, key, i in (("low", "cycles_low_median", 0), ("high", "cycles_high_median", 1),
                          ("trm", "cycles_trm_median", 1)):
        t = {"control": ctl[key], "supervision": sup[key], "entry_exit": ISR_OVERHEAD[i],
             "tail_chain": SUP_OVERHEAD[i], "background": bg[key] if bg is not None else 0.0}
        t["total"] = (t["control"] + t["supervision"] + t["entry_exit"] + t["tail_chain"]
                      + t["background"])
        t["share"] = 100 * t["total"] / BUDGET
        out[model] = t
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--opt", default="O2,Os", help="comma-separated -O levels (default O2,Os)")
    ap.add_argument(
        "--modes",
        default="force,speed",
        help="control modes: force (i_q reference, as bench_fw_step.c) and/or "
        "speed (speed loop on, 0 rad/s reference); default force,speed",
    )
    ap.add_argument(
        "--batch",
        type=int,
        default=80,
        help="steps per batch, a multiple of the injection period "
        "(8 samples at the default config; default 80)",
    )
    ap.add_argument("--batches", type=int, default=10, help="number of batches (default 10)")
    ap.add_argument(
        "--no-lto", action="store_true", help="build without -flto (one object per source)"
    )
    ap.add_argument("--isr", action="store_true",
                    help="also measure the drive's two interrupts of a period: the control "
                    "interrupt (fw_app_isr: ADC conversion, fw_step_into, duties) and the "
                    "supervision interrupt it pends (fw_app_supervise: integrity monitor, "
                    "protections, publication to the background), and their sum per period")
    ap.add_argument("--bg", action="store_true",
                    help="also measure the background loop (fw_app_background, one pass "
                    "after every period: CANopen, completing the period, faults, "
                    "telemetry, OD)")
    ap.add_argument("--by-source", action="store_true",
                    help="also break the counts down by source function, inlined code "
                    "attributed to its innermost function (DWARF line info)")
    ap.add_argument("--json", type=Path, help="also write the results as JSON")
    ap.add_argument("--keep-log", action="store_true", help="keep the QEMU exec log")
    a = ap.parse_args()
    check_tools()
    if a.batch * a.batches < 200:
        die("need at least 200 counted steps (batch x batches)")
    if a.batch * a.batches > 4000:
        die("at most 4000 counted steps (the harness's input buffer)")
    v = run(["qemu-system-arm", "--version"]).stdout.splitlines()[0]
    g = run(["arm-none-eabi-gcc", "--version"]).stdout.splitlines()[0]
    print(f"tools: {g}; {v}; board mps2-an386 (Cortex-M4F)")
    print(
        f"flags: {' '.join(CPU_FLAGS)} -O<level> -DNDEBUG{'' if a.no_lto else ' -flto'}"
        f" (-Os: {len(speed_sources('Os'))} control-path sources at "
        f"-{next(iter(speed_sources('Os').values()), 'Os')}, as the MinSizeRel image); "
        f"budget {BUDGET:.0f} cycles, "
        f"target <= {TARGET_SHARE * BUDGET:.0f}"
    )
    fp0 = source_fingerprint()
    print(f"sources: firmware_c/src + include + benchmarks/cm4, sha256 {fp0}")
    results = []
    modes = [m.strip() for m in a.modes.split(",") if m.strip()]
    if not modes or any(m not in ("force", "speed") for m in modes):
        die("--modes takes force and/or speed")
    for opt in [o.strip() for o in a.opt.split(",") if o.strip()]:
        elf = build(opt, OUT / opt, lto=not a.no_lto)
        for mode in modes:
            for kind in ["step", *(["isr", "sup"] if a.isr else []),
                         *(["bg"] if a.bg else [])]:
                res = measure(opt, mode, elf, a.batch, a.batches, a.keep_log, kind,
                              a.by_source)
                report(res)
                results.append(res)
    print(
        "\nsummary (instructions/step median; cycles/step low..high; % of budget incl. ISR "
        "entry/exit):"
    )
    for r in results:
        lo, hi = r["cycles_low_median"], r["cycles_high_median"]
        if r["mode"].endswith("+bg"):
            print(
                f"  -{r['opt']:<3} {r['mode']:<6} {r['insns_per_step_median']:7.1f} insns  "
                f"{lo:5.0f} .. {hi:5.0f} cycles per background pass  "
                f"{100 * lo / BUDGET:4.1f} .. {100 * hi / BUDGET:4.1f} % of a period  "
                f"(worst pass {r['cycles_high_max_step']} cycles)"
            )
            continue
        if r["mode"].endswith("+sup"):
            print(
                f"  -{r['opt']:<3} {r['mode']:<6} {r['insns_per_step_median']:7.1f} insns  "
                f"{lo:5.0f} .. {hi:5.0f} cycles  "
                f"{100 * (lo + SUP_OVERHEAD[0]) / BUDGET:4.1f} .. "
                f"{100 * (hi + SUP_OVERHEAD[1]) / BUDGET:4.1f} % (incl. tail-chaining "
                f"{SUP_OVERHEAD[1]})  trm {r['cycles_trm_median']:.0f}  "
                f"(worst step {r['cycles_high_max_step']} cycles)"
            )
            continue
        print(
            f"  -{r['opt']:<3} {r['mode']:<6} {r['insns_per_step_median']:7.1f} insns  "
            f"{lo:5.0f} .. {hi:5.0f} cycles  "
            f"{100 * (lo + ISR_OVERHEAD[0]) / BUDGET:4.1f} .. "
            f"{100 * (hi + ISR_OVERHEAD[1]) / BUDGET:4.1f} %  "
            f"margin to 50 % (worst step): "
            f"{TARGET_SHARE * BUDGET - r['cycles_high_max_step'] - ISR_OVERHEAD[1]:+.0f} cycles"
        )
    by = {(r["opt"], r["mode"]): r for r in results}
    for (opt, mode), r in by.items():
        if not mode.endswith("+isr"):
            continue
        lo, hi = r["cycles_low_median"], r["cycles_high_median"]
        tm = r["cycles_trm_median"]
        print(f"  -{opt:<3} {mode:<9} control interrupt <= {ISR_TARGET} cycles (median step): "
              f"low model {lo:.0f} -> {'meets' if lo <= ISR_TARGET else 'MISSES'}, "
              f"high model {hi:.0f} -> {'meets' if hi <= ISR_TARGET else 'MISSES'}, "
              f"trm model {tm:.0f} -> {'meets' if tm <= ISR_TARGET else 'MISSES'}")
        sup = by.get((opt, mode.replace("+isr", "+sup")))
        bg = by.get((opt, mode.replace("+isr", "+bg")))
        base = mode.replace("+isr", "")
        if sup is not None:
            for with_bg in (False, True) if bg is not None else (False,):
                for model, t in period_totals(r, sup, bg if with_bg else None).items():
                    parts = (f"control {t['control']:.0f} + supervision "
                             f"{t['supervision']:.0f} + entry/exit {t['entry_exit']} + "
                             f"tail-chaining {t['tail_chain']}")
                    what = "control + supervision"
                    if with_bg:
                        parts += f" + background {t['background']:.0f}"
                        what += " + background"
                    print(f"  -{opt:<3} {base:<9} per period, {model:<4} model: {what} = "
                          f"{t['total']:.0f} cycles ({t['share']:.1f} % of the period)  "
                          f"[{parts}]")
        if bg is not None:
            # the worst interrupts and the worst background pass in one period, high model
            sup_w = sup["cycles_high_max_step"] + SUP_OVERHEAD[1] if sup is not None else 0
            tot = (r["cycles_high_max_step"] + ISR_OVERHEAD[1] + sup_w
                   + bg["cycles_high_max_step"])
            sup_txt = (f"supervision {sup['cycles_high_max_step']} + tail-chaining "
                       f"{SUP_OVERHEAD[1]} + " if sup is not None else "")
            print(f"  -{opt:<3} {base:<9} one period, worst of each (high "
                  f"model): control {r['cycles_high_max_step']} + entry/exit "
                  f"{ISR_OVERHEAD[1]} + {sup_txt}background pass "
                  f"{bg['cycles_high_max_step']} = "
                  f"{tot} of {BUDGET:.0f} cycles -> "
                  f"{'fits' if tot <= BUDGET else 'DOES NOT FIT'} ({100 * tot / BUDGET:.0f} %)")
    for r in results:
        r["source_sha256_12"] = fp0
        r["lto"] = not a.no_lto
    if a.json:
        a.json.write_text(json.dumps(results, indent=2))
    if source_fingerprint() != fp0:
        print(
            "WARNING: the sources changed while this ran; the -O levels may have measured "
            "different code. Run again.",
            file=sys.stderr,
        )
        return 3
    return 0


if __name__ == "__main__":
    sys.exit(main())
