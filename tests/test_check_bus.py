"""``cobra check-bus`` against the emulated bus: every mismatch with the configuration is named."""
from __future__ import annotations

import json
import time


from cobra_cli.main import main
from hardware import control_table as ct
from hardware.config import EXAMPLE_CONFIG as EXAMPLE, JointConfig, load_bus_config
from hardware.driver import DynamixelBus
from hardware.emulator import EmulatorProcess
from hardware.faults import parse_fault
from hardware.plant import KinematicPlant


def start(emulators: list[EmulatorProcess], **kw) -> EmulatorProcess:
    emu = EmulatorProcess(KinematicPlant, **kw)
    emu.start()
    emulators.append(emu)
    return emu


def test_a_bus_that_matches_reports_every_servo_and_exits_0(emulators, capsys) -> None:
    emu = start(emulators)
    # as after a first `cobra record`: the configuration's mode and limits are written
    assert main(["check-bus", "--config", str(EXAMPLE), "--port", emu.port, "--json"]) == 1  # factory limits
    doc = json.loads(capsys.readouterr().out)
    assert [s["id"] for s in doc["servos"]] == list(range(1, 12))
    assert all(s["model_number"] == 1100 for s in doc["servos"])
    assert doc["servos"][0]["registers"]["Present Input Voltage"] == 120
    # the emulated servos come with the factory's 0..4095: the 90 deg joint limit gives 1024..3072
    assert doc["mismatches"][0] == ("joint 1 (ID 1): position limits 0..4095 pulses, the configuration's joint "
                                    "limit gives 1024..3072 (cobra record writes them at connect)")
    assert len(doc["mismatches"]) == 11
    bus = DynamixelBus(load_bus_config(EXAMPLE).with_port(emu.port))
    bus.connect()  # writes the limits, as `cobra record` does
    bus.close()
    assert main(["check-bus", "--config", str(EXAMPLE), "--port", emu.port]) == 0
    out = capsys.readouterr().out
    assert "all 11 servos match the configuration" in out
    row6 = next(line.split() for line in out.splitlines() if line.split()[:2] == ["6", "6"])
    assert row6 == ["6", "6", "1100", "46", "3", "(position)", "1024..3072", "12.0", "30", "off"]
    assert emu.stats().torque_off_s == {} and [emu.register(i, ct.TORQUE_ENABLE) for i in range(1, 12)] == [0] * 11


def test_every_mismatch_gets_one_line_naming_the_servo(emulators, capsys) -> None:
    # ID 11 missing, ID 12 not configured, another model number
    joints = [JointConfig(k, k) for k in range(1, 11)] + [JointConfig(11, 12)]
    emu = start(emulators, joints=joints, model_number=1120)
    assert main(["check-bus", "--config", str(EXAMPLE), "--port", emu.port]) == 1
    out = capsys.readouterr().out
    assert "joint 11 (ID 11): no answer to ping (wired? powered? another ID or baud rate?)" in out
    assert "ID 12 (model number 1120) answers but is not in the configuration" in out
    assert "joint 3 (ID 3): model number 1120, the configuration expects 1100 ([servo] model_number)" in out
    assert "   11  11      -  no answer" in out


def test_a_hardware_error_and_a_low_supply_are_named(emulators, capsys) -> None:
    emu = start(emulators)
    bus = DynamixelBus(load_bus_config(EXAMPLE).with_port(emu.port))
    bus.connect()
    bus.torque_on()  # faults count from the first torque on
    emu.inject(parse_fault("voltage:2"))
    emu.inject(parse_fault("overload:4"))
    time.sleep(0.05)
    bus.torque_off()
    bus.close()
    assert main(["check-bus", "--config", str(EXAMPLE), "--port", emu.port]) == 1
    out = capsys.readouterr().out
    assert "joint 2 (ID 2): input voltage 8.5 V outside its limits 9.5..16.0 V (supply or wiring)" in out
    assert "joint 4 (ID 4): hardware error (overload); reboot or power-cycle the servo" in out


def test_no_port_is_an_error_naming_it(capsys) -> None:
    assert main(["check-bus", "--config", str(EXAMPLE), "--port", "/nonexistent/tty"]) == 1
    assert "cannot open serial port /nonexistent/tty" in capsys.readouterr().err
