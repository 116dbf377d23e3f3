"""Shared by the bench tests: skip when the simulator libraries are not built."""

from __future__ import annotations

import pytest


def sim_available() -> bool:
    """Whether the simulator library and the drive application library both load."""
    try:
        from sim_fallback import _lib

        _lib.lib()
        from protocols import _clib

        _clib.load_app()
        return True
    except Exception:  # noqa: BLE001
        return False


needs_sim = pytest.mark.skipif(not sim_available(), reason="simulator libraries not built")
