"""The ctypes mirrors in sim_fallback/_lib.py match the C layout exactly."""

import ctypes as C
from pathlib import Path

import pytest

from sim_fallback import _lib


def _members(mirror, prefix="", base=0):
    """(path, offset) of every member; a nested structure (fw_config_t's parts) is
    listed, then each of its members as ``part.leaf`` with its offset in the whole."""
    for name, typ in mirror._fields_:
        off = base + getattr(mirror, name).offset
        yield prefix + name, off
        if isinstance(typ, type) and issubclass(typ, C.Structure):
            yield from _members(typ, prefix + name + ".", off)


@pytest.mark.parametrize("type_name", sorted(_lib.MIRRORS))
def test_mirror_matches_c_layout(type_name):
    L = _lib.lib()
    mirror = _lib.MIRRORS[type_name]
    assert L.sim_layout_sizeof(type_name.encode()) == C.sizeof(mirror), "sizeof differs"
    for name, off in _members(mirror):
        off_c = L.sim_layout_offsetof(type_name.encode(), name.encode())
        assert off_c >= 0, f"{type_name}.{name} unknown to C (mirror has an extra field)"
        assert off_c == off, f"{type_name}.{name} offset"


def test_fw_config_leaves_all_checked():
    """Every leaf of the nested fw_config_t mirror is in the C layout table (the
    generator follows the parts), and the flat attributes alias the nested fields."""
    L = _lib.lib()
    leaves = _lib.FwConfig.leaves()
    assert len(leaves) == L.fw_config_field_count()
    for path, off, _ in leaves.values():
        assert L.sim_layout_offsetof(b"fw_config_t", path.encode()) == off, path
    cfg = _lib.FwConfig()
    for k, name in enumerate(leaves):
        setattr(cfg, name, k + 1)
        part, leaf = leaves[name][0].split(".")
        assert getattr(getattr(cfg, part), leaf) == getattr(cfg, name) == k + 1


def test_fw_config_field_table_matches_mirror():
    """fw_config_field() (the firmware's own table) agrees with the mirror."""
    L = _lib.lib()
    n = L.fw_config_field_count()
    names = {}
    for i in range(n):
        f = L.fw_config_field(i).contents
        names[f.name.decode()] = (f.offset, f.is_int, f.is_signed)
    mirror = {name: (off, int(t in (C.c_uint32, C.c_int32)), int(t is C.c_int32))
              for name, (_, off, t) in _lib.FwConfig.leaves().items()}
    assert names == mirror
    assert [L.fw_config_field(i).contents.name.decode() for i in range(n)] == list(
        _lib.FwConfig.leaves()), "field table order"


def test_fw_ctrl_sizeof_consistent():
    L = _lib.lib()
    assert L.fw_ctrl_sizeof() == L.sim_layout_sizeof(b"fw_ctrl_t") > 0


def test_config_roundtrip_through_c():
    """A config written from Python is what the firmware stores."""
    from sim_fallback import Firmware, fw_config, load_motor

    cfg = fw_config(load_motor("iron_core_linear"), "sogi", u_inj_V=25.0)
    fw = Firmware(cfg)
    assert fw.init_status == 0
    L = _lib.lib()
    L.fw_get_config.restype = C.POINTER(_lib.FwConfig)
    L.fw_get_config.argtypes = [C.c_void_p]
    stored = L.fw_get_config(fw.handle).contents
    assert stored.as_dict() == cfg.as_dict()


def test_snapshot_as_dict_reads_every_field_as_getattr():
    """FwSnapshot.as_dict reads the structure in one struct.unpack_from (offsets and
    padding from the mirror): every field, in order, with the value and type that
    getattr gives, arrays as lists, on a snapshot of a running drive and on one with a
    distinct byte pattern in every position."""
    import math

    from sim_fallback import Sim

    def by_getattr(snap):
        out = {}
        for name, _ in snap._fields_:
            v = getattr(snap, name)
            out[name] = list(v) if isinstance(v, C.Array) else v
        return out

    with Sim("paper_salient", seed=3) as s:
        s.enable("speed")
        s.advance(6000)
        s.firmware.snapshot()  # fills the firmware object's FwSnapshot
        running = s.firmware._snap
    patterned = _lib.FwSnapshot()
    C.memmove(C.addressof(patterned), bytes((7 * i + 1) % 251 for i in range(C.sizeof(patterned))),
              C.sizeof(patterned))
    for snap in (running, patterned):
        got, want = snap.as_dict(), by_getattr(snap)
        assert list(got) == list(want)
        for k, w in want.items():
            g = got[k]
            assert type(g) is type(w), k
            same = [a == b or (math.isnan(a) and math.isnan(b)) for a, b in
                    zip(g if isinstance(g, list) else [g], w if isinstance(w, list) else [w],
                        strict=True)]
            assert all(same), (k, g, w)
    assert running.as_dict()["step_count"] > 0


def test_the_loaded_library_is_built_from_these_sources():
    assert _lib._mismatch(_lib.lib()) is None


def test_a_library_of_another_layout_is_named_stale():
    """A library left in build/ by an older checkout reports other sizes: refused with
    the structure and both sizes (checked against a stand-in that differs in one)."""
    real = _lib.lib()

    class Stale:
        def sim_layout_sizeof(self, name):
            n = real.sim_layout_sizeof(name)
            return n + 4 if name == b"fw_snapshot_t" else n

        def fw_config_field_count(self):
            return real.fw_config_field_count()

    why = _lib._mismatch(Stale())
    assert why is not None and "fw_snapshot_t" in why
    assert str(C.sizeof(_lib.FwSnapshot)) in why and str(C.sizeof(_lib.FwSnapshot) + 4) in why


def test_a_stale_library_named_by_the_user_is_a_one_line_error(tmp_path):
    """$PMLSM_SIM_LIB pointing at a library without this checkout's symbols: one line
    naming the file, no traceback, no silent fallback to another library."""
    import os
    import shutil
    import subprocess
    import sys
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler")
    src = tmp_path / "old.c"
    src.write_text("#include <stddef.h>\nsize_t sim_layout_sizeof(const char *t) "
                   "{ (void)t; return 1; }\n")
    so = tmp_path / "libpmlsm_sim.so"
    subprocess.run([cc, "-shared", "-fPIC", "-o", str(so), str(src)], check=True)
    env = dict(os.environ, PMLSM_SIM_LIB=str(so))
    code = ("from sim_fallback import _lib\n"
            "try:\n    _lib.lib()\nexcept OSError as e:\n    print(e)\n")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, timeout=60, cwd=Path(__file__).resolve().parents[2])
    assert out.returncode == 0, out.stderr
    line = out.stdout.strip()
    assert "\n" not in line and str(so) in line and "built from other sources" in line
