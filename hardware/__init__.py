"""Driving and recording COBRA through dynamixel-sdk, and a servo-bus emulator.

Modules:

* :mod:`hardware.config` - the bus configuration file (TOML/YAML) as typed, validated objects.
* :mod:`hardware.units` - raw Dynamixel units and the joint-angle convention.
* :mod:`hardware.control_table` - the XH540-W270 control table.
* :mod:`hardware.driver` - :class:`~hardware.driver.DynamixelBus`, through ``dynamixel_sdk``.
* :mod:`hardware.recorder` - stream a gait and record the run, with the safety stops.
* :mod:`hardware.runwriter` - the crash-safe incremental run writer.
* :mod:`hardware.protocol` - Protocol 2.0 packets (CRC-16, byte stuffing, parser).
* :mod:`hardware.emulator`, :mod:`hardware.plant`, :mod:`hardware.faults` - the bus emulator
  on a pty, what moves its servos, and the faults it can inject.
"""
