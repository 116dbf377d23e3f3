"""The C tests' motor data (tests/c/test_motors.h) are the shipped motor files' values:
each `c-><part>.<field> = <value>f;` is compared, as a number, with the motor file."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from sim_fallback._motors import tomllib

REPO = Path(__file__).resolve().parents[2]


def test_c_test_motor_data_equal_the_motor_files():
    src = (REPO / "tests" / "c" / "test_motors.h").read_text()
    funcs = re.findall(r"void test_motor_(\w+)\(fw_config_t \*c\) \{(.*?)\n\}", src, re.S)
    assert funcs, "no test_motor_<name>() in test_motors.h"
    for name, body in funcs:
        motor = tomllib.loads((REPO / "sim_fallback" / "motors" / f"{name}.toml").read_text())
        flat = {k: v for section in motor.values() if isinstance(section, dict)
                for k, v in section.items()}
        fields = re.findall(r"c->\w+\.(\w+) = ([-+0-9.eE]+)f;", body)
        assert len(fields) >= 6, name
        for field, value in fields:
            assert field in flat, f"{name}: {field} not in the motor file"
            assert float(value) == pytest.approx(float(flat[field]), rel=1e-6), (name, field)
