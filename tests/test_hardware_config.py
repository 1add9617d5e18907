"""Bus configuration files: the example loads, YAML equals TOML, and every mistake is named."""
from __future__ import annotations

import copy
import math
import re
import tomllib
from pathlib import Path
from typing import Any

import pytest

from cobra_model.errors import InputError
from hardware.config import EXAMPLE_CONFIG as EXAMPLE, BusConfig, bus_config_from_dict, load_bus_config
from hardware.control_table import OperatingMode



def example_dict() -> dict[str, Any]:
    with EXAMPLE.open("rb") as fh:
        return tomllib.load(fh)


def test_example_configuration_loads() -> None:
    config = load_bus_config(EXAMPLE)
    assert config.port == "/dev/ttyUSB0"
    assert config.baud_rate == 1_000_000
    assert config.servo_ids == tuple(range(1, 12))
    assert config.servo.operating_mode is OperatingMode.POSITION
    assert config.servo.position_p_gain == 800
    assert config.joint_limit_rad == pytest.approx(math.pi / 2)
    assert config.control_period_s == pytest.approx(0.02)
    assert config.source == str(EXAMPLE)
    # The defaults of BusConfig are the example's values.
    assert config.to_json() == BusConfig(port="/dev/ttyUSB0").to_json()


def test_yaml_reads_like_toml(tmp_path: Path) -> None:
    yaml = pytest.importorskip("yaml")
    data = example_dict()
    data["joints"][3]["zero_offset_deg"] = -12.5
    data["joints"][3]["direction"] = -1
    path = tmp_path / "bus.yaml"
    path.write_text(yaml.safe_dump(data))
    config = load_bus_config(path)
    assert config.joints[3].zero_offset_rad == pytest.approx(math.radians(-12.5))
    assert config.joints[3].direction == -1
    assert config.to_json() == bus_config_from_dict(data, source="x").to_json()


def _set(data: dict, path: tuple, value: Any) -> dict:
    data = copy.deepcopy(data)
    target = data
    for key in path[:-1]:
        target = target[key]
    if value is _DELETE:
        del target[path[-1]]
    else:
        target[path[-1]] = value
    return data


_DELETE = object()


@pytest.mark.parametrize("path, value, expected", [
    (("bus", "port"), _DELETE, r"\[bus\]: missing required key 'port'"),
    (("bus", "baud_rate"), 12345, r"\[bus\]: baud_rate: expected one of 9600, .*got 12345"),
    (("bus", "baud_rate"), 1e6, r"baud_rate: expected one of .*got 1000000.0"),
    (("bus", "control_rate_hz"), 0, r"control_rate_hz: expected a number in \(0, 1000\], got 0"),
    (("bus", "control_rate_hz"), 400.0, r"control_rate_hz = 400: one cycle needs at least 3\.\d+ ms"),
    (("bus", "max_consecutive_failures"), True, r"max_consecutive_failures: expected an integer"),
    (("bus", "prot"), "/dev/x", r"\[bus\]: unknown key\(s\) 'prot'"),
    (("bus", "bus_watchdog_ms"), 0, r"bus_watchdog_ms: expected an integer in 20\.\.2540, got 0"),
    (("bus", "bus_watchdog_ms"), 110, r"bus_watchdog_ms = 110: the servos count it in 20 ms units"),
    (("bus", "bus_watchdog_ms"), 40, r"bus_watchdog_ms = 40: shorter than 3 control periods \(60 ms at 50 Hz\).*"
                                     r"expected at least 60"),
    (("servo", "position_p_gain"), 20000, r"\[servo\]: position_p_gain: expected an integer in 0\.\.16383"),
    (("servo", "model_number"), 1060, r"\[servo\]: model_number = 1060 is no X-series servo with this control "
                                       r"table; expected one of 1000 \(XH430-W350\), .*1100 \(XH540-W270\)"),
    (("servo", "pwm_limit"), 900, r"pwm_limit: expected an integer in 0\.\.885, got 900"),
    (("servo", "operating_mode"), "velocity", r"operating_mode: expected one of 'position'"),
    (("servo", "joint_limit_deg"), 120.0, r"joint_limit_deg: expected a number in \(0, 90\]"),
    (("servo", "postion_d_gain"), 3, r"\[servo\]: unknown key\(s\) 'postion_d_gain'"),
    (("joints", 4, "direction"), 0, r"joints\[4\] \(joint 5\): direction: expected one of 1, -1, got 0"),
    (("joints", 4, "id"), 3, r"joints: servo id\(s\) \[3\] used by more than one joint"),
    (("joints", 4, "id"), _DELETE, r"joints\[4\] \(joint 5\): missing required key 'id'"),
    (("joints", 4, "joint"), 4, r"joints\[4\]: joint 4 is listed twice"),
    (("joints", 4, "joint"), 12, r"joints\[4\]: joint: expected an integer in 1\.\.11, got 12"),
    (("joints", 4, "zero_offset_deg"), 95.0, r"zero_offset_deg = 95: .*0\.\.4095 pulse range"),
    (("joints",), [], r"joints: expected a list of 11 entries \(\[\[joints\]\] tables\), got 0"),
    (("mocap",), {}, r"unknown table\(s\) 'mocap'"),
])
def test_invalid_configurations_are_named(tmp_path: Path, path: tuple, value: Any, expected: str) -> None:
    data = _set(example_dict(), path, value)
    file = tmp_path / "bad.toml"
    file.write_text(_to_toml(data))
    with pytest.raises(InputError, match=re.escape(str(file)) + ".*" + expected):
        load_bus_config(file)


def test_unreadable_files(tmp_path: Path) -> None:
    broken = tmp_path / "broken.toml"
    broken.write_text("[bus\nport = 1")
    with pytest.raises(InputError, match="broken.toml: not valid TOML"):
        load_bus_config(broken)
    other = tmp_path / "bus.json"
    other.write_text("{}")
    with pytest.raises(InputError, match=r"bus.json: expected a \.toml, \.yaml or \.yml"):
        load_bus_config(other)
    with pytest.raises(FileNotFoundError, match=r"bus configuration .*missing\.toml does not exist"):
        load_bus_config(tmp_path / "missing.toml")


def _to_toml(data: dict[str, Any]) -> str:
    """Minimal TOML writer for the configuration's shape (tables of scalars, array of tables)."""

    def scalar(v: Any) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return f'"{v}"'
        if isinstance(v, dict):
            return "{}"
        if isinstance(v, list):
            return "[]"
        return repr(v)

    lines = []
    for name, table in data.items():
        if isinstance(table, list) and table and isinstance(table[0], dict):
            for entry in table:
                lines.append(f"[[{name}]]")
                lines.extend(f"{k} = {scalar(v)}" for k, v in entry.items())
        elif isinstance(table, dict):
            lines.append(f"[{name}]")
            lines.extend(f"{k} = {scalar(v)}" for k, v in table.items())
        else:
            lines.insert(0, f"{name} = {scalar(table)}")
    return "\n".join(lines) + "\n"
