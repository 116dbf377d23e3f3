"""The emulated board (firmware_c/boards/mps2_an386): the whole drive image on QEMU's
mps2-an386 with the simulator's plant compiled in as its virtual motor, reached as a
real drive is - CAN through python-can's ``slcan`` interface over a TCP socket, serial
telemetry through pyserial - by the ``canopen`` library as the outside master.

Builds the image once per session (skipped without arm-none-eabi-gcc or
qemu-system-arm, unless CI=true), writes boot blocks with
``sim_fallback.write_emu_boot_blob`` and runs QEMU on free ports in a temporary
folder. Also: the load machine's command line on the real plant (host library, no
QEMU); the slcan endpoint's libFuzzer harness runs with the others
(tests/python/test_protocol_fuzz.py).

The emulator is slower than real time: the enabled drive runs at about 0.3 drive
seconds per wall second here; the tests wait on the drive's own clock (0x2090:3, the
plant's period count), never on wall time.
"""

from __future__ import annotations

import ctypes as C
import math
import os
import re
import shutil
import signal
import socket
import struct
import subprocess
import time
import zlib
from pathlib import Path

import pytest

from protocols.generated.od_names import FW_VERSION_STRING

ROOT = Path(__file__).resolve().parents[2]
EDS = ROOT / "protocols" / "generated" / "pmlsm_drive.eds"
BOARD = "mps2_an386"
IMAGE = f"pmlsm_{BOARD}.elf"
F_PWM = 24000.0
HOST = "127.0.0.1"
CI = os.environ.get("CI", "").lower() == "true"


def _need(*tools: str) -> None:
    missing = [t for t in tools if shutil.which(t) is None]
    if missing:
        if CI:
            pytest.fail(f"{', '.join(missing)} required in CI for the emulated board")
        pytest.skip(f"{', '.join(missing)} not installed (apt-get install gcc-arm-none-eabi "
                    "qemu-system-arm); set CI=true to make this a failure")


# ---- the image ---------------------------------------------------------------------


@pytest.fixture(scope="session")
def emu_build(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """The image, built once per session: in $PMLSM_BUILD_DIR/emu-image (incremental;
    where the bench looks for it) or a temporary folder."""
    _need("arm-none-eabi-gcc", "qemu-system-arm")
    bd = os.environ.get("PMLSM_BUILD_DIR")
    build = (Path(bd) / "emu-image") if bd else tmp_path_factory.mktemp("emu-image")
    cfg = ["cmake", "-S", str(ROOT), "-B", str(build), "-G", "Ninja",
           "-DPMLSM_TARGET_CM4=ON", "-DCMAKE_BUILD_TYPE=MinSizeRel",
           f"-DCMAKE_TOOLCHAIN_FILE={ROOT / 'firmware_c/cmake/arm-none-eabi.cmake'}",
           f"-DPMLSM_BOARD={BOARD}"]
    subprocess.run(cfg, check=True, capture_output=True, text=True)
    # a clean target re-links (the size report is part of the link step's output)
    elf = build / "firmware_c" / "boards" / BOARD / IMAGE
    if elf.exists():
        elf.unlink()
    res = subprocess.run(["cmake", "--build", str(build), "--target", IMAGE], check=True,
                         capture_output=True, text=True)
    assert elf.is_file(), res.stdout
    return elf, res.stdout


def test_image_size(emu_build: tuple[Path, str]) -> None:
    elf, log = emu_build
    m = re.search(rf"^\s*(\d+)\s+(\d+)\s+(\d+)\s+\d+\s+[0-9a-f]+\s+\S*{IMAGE}", log, re.M)
    assert m, f"no Berkeley size line in the build output:\n{log}"
    text, data, bss = (int(g) for g in m.groups())
    print(f"{BOARD}: text={text} data={data} bss={bss}")
    # the drive (~70 KB) + the plant, libm and the board; RAM: the drive, the plant
    # (~96 KiB of sim_t in a 128 KiB block) and the UART rings, in 4 MiB
    assert 80_000 < text < 400_000
    assert data < 1024
    assert bss < 1024 * 1024
    nm = subprocess.run(["arm-none-eabi-nm", str(elf)], capture_output=True, text=True,
                        check=True).stdout
    # no allocator and no printf in the image (caller-owned state, own formatting)
    assert not re.search(r"\b(malloc|_malloc_r|_sbrk|printf|_vfprintf_r|strtod)\b", nm), nm


# ---- QEMU --------------------------------------------------------------------------


def _free_ports(n: int) -> list[int]:
    from sim_fallback.emu import free_ports

    return free_ports(n)


def qemu_command(elf: Path, boot: str | None, ports: list[int]) -> list[str]:
    """The emulated board's command line (firmware_c/boards/mps2_an386/CMakeLists.txt):
    nodelay=on, or every reply of the board waits for the host's delayed ACK (~40 ms)."""
    cmd = ["qemu-system-arm", "-M", "mps2-an386", "-nographic", "-monitor", "none",
           "-icount", "shift=0,sleep=off", "-semihosting-config", "enable=on,target=native",
           "-kernel", str(elf)]
    if boot is not None:
        cmd += ["-device", f"loader,file={boot},addr=0x21000000"]
    for p in ports:
        cmd += ["-serial", f"tcp:{HOST}:{p},server=on,wait=off,nodelay=on"]
    return cmd


class Emu:
    """One emulated board: QEMU in ``folder`` (its boot block ``boot.bin`` there)."""

    def __init__(self, elf: Path, folder: Path, boot: str | None = "boot.bin") -> None:
        self.folder = folder
        self.can_port, self.tel_port, self.load_port = _free_ports(3)
        self.log = folder / "qemu.log"
        # a second board in the same folder appends: its console starts here
        self._log_start = self.log.stat().st_size if self.log.exists() else 0
        self._logf = open(self.log, "ab")
        self.proc = subprocess.Popen(
            qemu_command(elf, boot, [self.can_port, self.tel_port, self.load_port]),
            cwd=folder, stdin=subprocess.DEVNULL, stdout=self._logf, stderr=subprocess.STDOUT)
        self._load: socket.socket | None = None
        self._buf = b""

    def wait_listening(self, timeout_s: float = 20.0) -> None:
        deadline = time.monotonic() + timeout_s
        while True:
            assert self.proc.poll() is None, f"QEMU exited: {self.console()}"
            try:
                self._load = socket.create_connection((HOST, self.load_port), timeout=5.0)
                return
            except OSError:
                assert time.monotonic() < deadline, "QEMU did not listen"
                time.sleep(0.05)

    def console(self) -> str:
        """This board's console output so far (not an earlier board's in the folder)."""
        if not self._logf.closed:
            self._logf.flush()
        return self.log.read_bytes()[self._log_start:].decode(errors="replace")

    def wait_console(self, text: str, timeout_s: float = 20.0) -> str:
        """The console once it shows ``text``: QEMU listens on its sockets before the
        firmware has printed its boot line, so a test that reads the console at once
        after connecting can read it before the line is there."""
        deadline = time.monotonic() + timeout_s
        while text not in (out := self.console()):
            assert self.proc.poll() is None and time.monotonic() < deadline, \
                f"no {text!r} on the console: {out!r}"
            time.sleep(0.05)
        return out

    def load(self, line: str) -> str:
        """One line to the virtual load machine (UART2), its reply."""
        assert self._load is not None
        self._load.sendall(line.encode() + b"\n")
        while b"\n" not in self._buf:
            chunk = self._load.recv(1024)
            assert chunk, "the load machine closed its link"
            self._buf += chunk
        reply, _, self._buf = self._buf.partition(b"\n")
        return reply.decode()

    def status(self) -> dict[str, float]:
        reply = self.load("status")
        assert reply.startswith("ok status "), reply
        return {k: float(v) for k, v in (t.split("=") for t in reply.split()[2:])}

    def stats(self) -> dict[str, str]:
        reply = self.load("stats")
        assert reply.startswith("ok stats "), reply
        return dict(t.split("=", 1) for t in reply.split()[2:])

    def stop(self, sig: int = signal.SIGTERM) -> int:
        if self._load is not None:
            self._load.close()
            self._load = None
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        try:
            rc = self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            rc = self.proc.wait()
        self._logf.close()
        return rc


@pytest.fixture
def make_emu(emu_build: tuple[Path, str]):
    elf = emu_build[0]
    started: list[Emu] = []

    def make(folder: Path, boot: str | None = "boot.bin", wait: bool = True) -> Emu:
        e = Emu(elf, folder, boot)
        started.append(e)
        if wait:
            e.wait_listening()
        return e

    yield make
    for e in started:
        e.stop(signal.SIGKILL)


def _boot(folder: Path, **kw) -> Path:
    from sim_fallback import write_emu_boot_blob

    return write_emu_boot_blob(folder / "boot.bin", **kw)


class Master:
    """The outside master: python-can slcan over the board's CAN socket + canopen."""

    def __init__(self, emu: Emu) -> None:
        import can
        import canopen

        self.bus = can.Bus(interface="slcan", channel=f"socket://{HOST}:{emu.can_port}",
                           sleep_after_open=0)
        self.net = canopen.Network(self.bus)
        self.net.connect()
        self.node = canopen.RemoteNode(1, str(EDS))
        self.net.add_node(self.node)
        self.node.sdo.RESPONSE_TIMEOUT = 2.0
        self.pdo: dict[int, list[tuple[float, bytes]]] = {}
        for cob in (0x281, 0x481):  # TPDO2 (position, velocity), TPDO4 (drive time, scale)
            self.pdo[cob] = []
            self.net.subscribe(cob, lambda c, d, ts: self.pdo[c].append((ts, bytes(d))))

    def sdo(self, index: int, sub: int | None = None):
        v = self.node.sdo[index]
        return v[sub] if sub is not None else v

    def drive_periods(self) -> int:
        return int(self.sdo(0x2090, 3).raw)

    def wait_drive_s(self, dt_s: float, timeout_s: float = 60.0) -> None:
        """Wait dt_s of the drive's time (its period count, not the wall clock)."""
        end = self.drive_periods() + int(dt_s * F_PWM)
        deadline = time.monotonic() + timeout_s
        while self.drive_periods() < end:
            assert time.monotonic() < deadline, "the drive's clock does not advance"
            time.sleep(0.02)

    def sync_series(self, n: int, cob: int, gap_s: float = 0.01) -> list[bytes]:
        """n SYNCs; the TPDO frames of cob they produced."""
        k0 = len(self.pdo[cob])
        for _ in range(n):
            self.net.sync.transmit()
            time.sleep(gap_s)
        deadline = time.monotonic() + 5.0
        while len(self.pdo[cob]) < k0 + n and time.monotonic() < deadline:
            time.sleep(0.01)
        return [d for _, d in self.pdo[cob][k0:]]

    def close(self) -> None:
        self.net.disconnect()


# ---- the load machine on the real plant (host library, no QEMU) --------------------


def test_vmotor_link_on_the_real_plant() -> None:
    """The load machine's commands act on the simulator's plant itself: a load above
    the static friction moves the mover against +x, ref_fault freezes the scale."""
    from sim_fallback import _lib, drive_params

    L = _lib.lib()
    L.sim_vmotor_link_sizeof.restype = C.c_size_t
    L.sim_vmotor_link_init.argtypes = [C.c_void_p, C.c_void_p, C.POINTER(_lib.SimPlantParams),
                                       C.c_double, C.c_void_p]
    L.sim_vmotor_link_push.restype = C.c_size_t
    L.sim_vmotor_link_push.argtypes = [C.c_void_p, C.c_uint8, C.c_char_p, C.c_size_t]
    L.sim_ref_sample.restype = C.c_uint8
    L.sim_ref_sample.argtypes = [C.c_void_p, C.POINTER(C.c_int32)]
    params, _ = drive_params("paper_salient", seed=3)
    sim = L.sim_new(C.byref(params))
    link = C.create_string_buffer(L.sim_vmotor_link_sizeof())
    assert L.sim_vmotor_link_init(link, sim, C.byref(params), 0.0, None) == 0
    out = C.create_string_buffer(512)

    def cmd(line: str) -> str:
        replies = []
        for b in (line + "\n").encode():
            n = L.sim_vmotor_link_push(link, b, out, len(out))
            if n:
                replies.append(out.raw[:n].decode())
        assert len(replies) == 1, replies
        return replies[0].rstrip("\n")

    try:
        off = (C.c_double * 3)(0.5, 0.5, 0.5)
        L.sim_plant_advance(sim, off, 0, 0.05, 20)  # PWM off, no load: at rest
        st = _lib.SimPlantState()
        L.sim_get_state(sim, C.byref(st))
        assert st.x_m == 0.0
        static_N = params.F_static_N
        assert cmd(f"load {static_N * 0.5:g}") == f"ok load {static_N * 0.5:g}"
        L.sim_plant_advance(sim, off, 0, 0.05, 20)
        L.sim_get_state(sim, C.byref(st))
        assert st.x_m == 0.0  # held by static friction
        assert cmd(f"load {static_N * 2:g}") == f"ok load {static_N * 2:g}"
        L.sim_plant_advance(sim, off, 0, 0.05, 20)
        L.sim_get_state(sim, C.byref(st))
        assert st.x_m < -1e-4 and st.v_mps < 0  # the load pushes against +x
        cnt = C.c_int32()
        assert L.sim_ref_sample(sim, C.byref(cnt)) == 1  # FW_REF_OK
        assert cmd("ref_fault 1") == "ok ref_fault 1"
        frozen = cnt.value
        L.sim_plant_advance(sim, off, 0, 0.05, 20)
        assert L.sim_ref_sample(sim, C.byref(cnt)) == 2 and cnt.value == frozen  # FAULT
        assert cmd("ref_fault 0") == "ok ref_fault 0"
        assert L.sim_ref_sample(sim, C.byref(cnt)) == 1 and cnt.value < frozen
        assert cmd("status") == (f"ok status periods=0 load={static_N * 2:g} ref_fault=0 "
                                 "overruns=0")
        assert cmd("load 1e7").startswith("err load '1e7' out of range")
    finally:
        L.sim_free(sim)


# ---- boot block refused --------------------------------------------------------------


def _patched(blob: bytes, off: int, data: bytes, crc: bool = True) -> bytes:
    b = bytearray(blob)
    b[off:off + len(data)] = data
    if crc:
        b[12:16] = struct.pack("<I", zlib.crc32(bytes(b[16:])) & 0xFFFFFFFF)
    return bytes(b)


_FW_U32 = int.from_bytes(bytes(int(x) for x in FW_VERSION_STRING.split(".")), "big")

BAD_BLOCKS = {
    "sizeof_config": (lambda b: _patched(b, 20, struct.pack("<I", 292)),
                      "emu boot block: sizeof(fw_config_t) 292, this image 412"),
    "sizeof_plant": (lambda b: _patched(b, 16, struct.pack("<I", 280)),
                     "emu boot block: sizeof(sim_plant_params_t) 280, this image 288"),
    "version": (lambda b: _patched(b, 24, struct.pack("<I", 0x000200)),
                f"emu boot block: firmware version 0x000200, this image 0x{_FW_U32:06X} "
                f"({FW_VERSION_STRING})"),
    "node_id": (lambda b: _patched(b, 28, b"\x00"), "emu boot block: node id 0, allowed 1..127"),
    "crc": (lambda b: _patched(b, 200, b"\x55", crc=False), "emu boot block: CRC-32 0x"),
    "magic": (lambda b: _patched(b, 0, b"XXXX", crc=False), "emu boot block: magic 0x58585858"),
    "x0": (lambda b: _patched(b, 32, struct.pack("<d", math.nan)),
           "emu boot block: x0 nan, expected a finite number"),
    "path": (lambda b: _patched(b, 48, b"p" * 128),
             "emu boot block: flash file path not NUL-terminated"),
    "plant": (lambda b: _patched(b, 176, struct.pack("<d", -1.0)),  # R_ohm
              "emu boot block: sim_plant_params_t.R_ohm refused"),
    "no_block": (None, "emu boot block: magic 0x00000000"),
}


@pytest.mark.parametrize("case", sorted(BAD_BLOCKS))
def test_bad_boot_block_exits_naming_the_field(case, make_emu, tmp_path: Path) -> None:
    from sim_fallback import emu_boot_blob

    patch, line = BAD_BLOCKS[case]
    boot: str | None = "boot.bin"
    if patch is None:
        boot = None
    else:
        (tmp_path / "boot.bin").write_bytes(patch(emu_boot_blob()))
    emu = make_emu(tmp_path, boot, wait=False)
    rc = emu.proc.wait(timeout=30)
    out = emu.console()
    assert rc == 2, out
    lines = [t for t in out.splitlines() if t.startswith("emu boot block:")]
    assert len(lines) == 1 and lines[0].startswith(line), out
    print(lines[0])


def test_good_boot_block_boots(make_emu, tmp_path: Path) -> None:
    """The unpatched block boots (so the cases above fail on their field alone)."""
    _boot(tmp_path)
    emu = make_emu(tmp_path)
    assert emu.status()["periods"] > 0
    assert "mps2_an386: drive node 1, firmware" in emu.wait_console("mps2_an386: drive node")


# ---- the drive over CANopen ------------------------------------------------------------


def test_drive_over_canopen(make_emu, tmp_path: Path) -> None:
    """Identity, TPDO4 on the drive's clock, an enabled speed loop with a load step, the
    telemetry stream, the costs per period."""
    import serial

    from protocols import serial_link as sl
    from sim_fallback import drive_params
    from sim_fallback._emu_blob import firmware_version_u32

    x0 = 0.0123
    _boot(tmp_path, x0_m=x0, seed=1, nvm_path="")
    params, _ = drive_params("paper_salient", seed=1)
    emu = make_emu(tmp_path)
    m = Master(emu)
    try:
        # what the port makes of the drive
        assert m.sdo(0x2090, 1).raw == 2  # FW_DRIVE_EMULATED
        assert m.sdo(0x2090, 2).raw == BOARD
        assert m.sdo(0x2040).raw == firmware_version_u32()
        assert m.sdo(0x1010, 1).raw == 0  # no flash file: no non-volatile memory
        # TPDO4 on SYNC: the drive's period index between the plant's period counts
        # read just before and after; the scale's count at the mover's true position
        m.node.nmt.state = "OPERATIONAL"
        time.sleep(0.1)
        before = emu.status()["periods"]
        frames = m.sync_series(20, 0x481)
        after = emu.status()["periods"]
        assert len(frames) == 20
        t4 = [struct.unpack("<Ii", d) for d in frames]
        times = [t for t, _ in t4]
        assert all(b > a for a, b in zip(times, times[1:], strict=False)), times
        assert before - 1 <= times[0] and times[-1] <= after, (before, times, after)
        count0 = math.floor((x0 + params.ref_offset_m) / params.ref_res_m)
        assert {c for _, c in t4} == {count0}
        # enable in speed mode over SDO: 100 r/min on the paper motor = 0.32 m/s
        v_ref = 320_000  # um/s
        m.sdo(0x6060).raw = 9
        m.sdo(0x60FF).raw = v_ref
        for cw in (6, 7, 15):
            m.sdo(0x6040).raw = cw
        w0, p0 = time.monotonic(), m.drive_periods()
        m.wait_drive_s(0.45)
        speed = (m.drive_periods() - p0) / F_PWM / (time.monotonic() - w0)
        assert m.sdo(0x6041).raw & 0x6F == 0x27, hex(m.sdo(0x6041).raw)  # OPERATION ENABLED
        assert m.sdo(0x603F).raw == 0
        # the estimate and the scale (the truth) follow the reference
        frames2 = m.sync_series(10, 0x281)
        v_est = [struct.unpack("<ii", d)[1] for d in frames2]
        assert all(abs(v - v_ref) < 0.1 * v_ref for v in v_est), v_est
        frames4 = m.sync_series(2, 0x481, gap_s=0.3)
        (ta, ca), (tb, cb) = (struct.unpack("<Ii", d) for d in frames4)
        v_scale = (cb - ca) * params.ref_res_m / ((tb - ta) / F_PWM)
        assert abs(v_scale - v_ref * 1e-6) < 0.1 * v_ref * 1e-6, (v_scale, ta, tb)
        # a load step from the load machine: 2 N m on the paper motor's 30.6 mm radius
        p_step = m.drive_periods()
        assert emu.load("load 65") == "ok load 65"
        v_dip: list[int] = []
        while m.drive_periods() < p_step + 0.15 * F_PWM:  # 150 ms of the drive's time
            v_dip += [struct.unpack("<ii", d)[1] for d in m.sync_series(5, 0x281, 0.02)]
        assert min(v_dip) < 0.95 * v_ref, v_dip  # the load slowed the mover ...
        m.wait_drive_s(0.4)
        v_end = [struct.unpack("<ii", d)[1] for d in m.sync_series(5, 0x281)]
        assert all(abs(v - v_ref) < 0.05 * v_ref for v in v_end), v_end  # ... it recovered
        assert m.sdo(0x603F).raw == 0
        st = emu.status()
        assert st["load"] == 65.0 and st["overruns"] == 0
        # the serial telemetry stream: a frame every 24 periods (0x2060:1)
        port = serial.serial_for_url(f"socket://{HOST}:{emu.tel_port}", timeout=0.1)
        rx = sl.Receiver()
        got: list[sl.Frame] = []
        t_end = time.monotonic() + 1.5
        while time.monotonic() < t_end:
            got += rx.feed(port.read(4096))
        port.close()
        tel = [sl.parse_telemetry(f.payload) for f in got if f.type == sl.FrameType.TELEMETRY]
        assert len(tel) > 50, (len(tel), rx.errors)
        steps = [t.step for t in tel]
        gaps = [b - a for a, b in zip(steps, steps[1:], strict=False)]
        assert gaps.count(24) >= 0.95 * len(gaps), gaps[:50]
        assert rx.frames_bad <= 1  # the first frame may be cut by the connection
        # the costs of one period (instructions, -icount shift=0), read by the load machine
        s = emu.stats()
        print(f"emulated drive enabled: {speed:.3f} drive s per wall s")
        print("stats:", " ".join(f"{k}={v}" for k, v in s.items()))
        assert int(s["overruns"]) == 0 and int(s["sup_missed"]) == 0
        period_max = int(s["period"].split("/")[1].split("@")[0])
        assert period_max < int(s["timer_insn"]) // 2, s  # the worst period in half a timer
    finally:
        m.close()


def test_config_saved_survives_restart_and_kill_closes_sockets(make_emu,
                                                               tmp_path: Path) -> None:
    """0x1010:1 'save' writes the flash page through to its host file; a new QEMU on
    the same block and file boots with it. Killing QEMU closes the CAN socket: the
    python-can bus raises on its next read instead of hanging."""
    import can

    _boot(tmp_path, nvm_path="flash.bin")
    emu = make_emu(tmp_path)
    m = Master(emu)
    try:
        assert m.sdo(0x1010, 1).raw == 1  # saves on command
        assert m.sdo(0x2050, 10).raw != pytest.approx(17.5)
        m.sdo(0x2050, 10).raw = 17.5  # i_max_A
        m.sdo(0x2060, 1).raw = 48  # telemetry decimation
        m.sdo(0x1010, 1).raw = 0x65766173  # 'save'
    finally:
        m.close()
    emu.stop()
    flash = tmp_path / "flash.bin"
    assert flash.stat().st_size == 2048
    n = struct.unpack_from("<I", flash.read_bytes())[0]
    assert 300 < n < 2048  # the header's block length: a block is stored
    emu = make_emu(tmp_path)
    assert "stored block state 2" in emu.wait_console("stored block state")  # LOADED
    m = Master(emu)
    try:
        assert m.sdo(0x2050, 10).raw == pytest.approx(17.5)
        assert m.sdo(0x2060, 1).raw == 48
    finally:
        m.net.disconnect()  # the bus alone from here
    bus = can.Bus(interface="slcan", channel=f"socket://{HOST}:{emu.can_port}",
                  sleep_after_open=0)
    try:
        bus.send(can.Message(arbitration_id=0x601, is_extended_id=False,
                             data=bytes([0x40, 0x40, 0x20, 0, 0, 0, 0, 0])))  # read 0x2040
        deadline = time.monotonic() + 5.0
        while True:
            msg = bus.recv(timeout=0.5)
            if msg is not None and msg.arbitration_id == 0x581:
                break
            assert time.monotonic() < deadline, "no SDO response"
        emu.proc.kill()
        emu.proc.wait(timeout=10)
        t0 = time.monotonic()
        with pytest.raises(can.CanError):
            for _ in range(50):
                bus.recv(timeout=0.2)
        assert time.monotonic() - t0 < 5.0
    finally:
        try:
            bus.shutdown()
        except can.CanError:
            pass  # closing writes "C": the socket is gone


def test_uart_byte_rates(make_emu, tmp_path: Path) -> None:
    """What QEMU moves through the board's UARTs per wall second (figures, printed; the
    only assertion: every byte sent was answered). CAN: 8-byte frames to an identifier
    nobody uses, each acknowledged with "z\\r"; load machine: 70-byte lines, each
    refused with one line."""
    _boot(tmp_path)
    emu = make_emu(tmp_path)
    can_sock = socket.create_connection((HOST, emu.can_port), timeout=10)
    try:
        can_sock.sendall(b"O\r")
        assert can_sock.recv(16) == b"\r"
        n = 400
        line = b"t7E58" + b"A5" * 8 + b"\r"
        t0 = time.monotonic()
        can_sock.sendall(line * n)
        got = b""
        while got.count(b"z\r") < n:
            chunk = can_sock.recv(65536)
            assert chunk, "the CAN link closed"
            got += chunk
        can_rate = n * len(line) / (time.monotonic() - t0)
    finally:
        can_sock.close()
    m = 200
    t0 = time.monotonic()
    assert emu._load is not None
    emu._load.sendall((b"x" * 69 + b"\n") * m)
    replies = 0
    buf = b""
    while replies < m:
        chunk = emu._load.recv(65536)
        assert chunk
        buf += chunk
        replies = buf.count(b"\n")
    load_rate = m * 70 / (time.monotonic() - t0)
    s = emu.stats()
    print(f"UART0 (CAN) host -> board {can_rate:.0f} B/s, UART2 host -> board {load_rate:.0f} "
          f"B/s; board counted can_rx={s['can_rx']} rx_lost={s['rx_lost']}")
    assert int(s["rx_lost"]) == 0
