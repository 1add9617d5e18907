"""Fault matrix of `cobra record`: what each fault does to the robot and to the run on disk.

Each case records the paper's gait for ``--duration`` seconds from the emulated bus
(:class:`hardware.emulator.EmulatorProcess`, servos without dynamics: each joint a 30 ms
first-order lag toward its goal, :class:`hardware.plant.KinematicPlant`) with one fault at
``--at`` seconds after the first torque on, and reports, measured on the emulator's clock (the robot's):

- how the recording ended (the recorder's stop status);
- the time from the fault to the last servo's torque off, or to its Bus Watchdog stop when the
  torque off cannot reach it (a cut bus cable);
- whether the partial run file reads as a run and ``cobra compare`` reproduces it (its joint
  metrics: a recording without motion capture is a joint-only run). Our simulation's servos
  (the nominal motor behind the position loop, each goal held until the next sample as the
  servos held it) are not the emulator's lag, so the joint RMSE is the gap between the two
  servo models, alike in every row: it shows that the run reproduces, not a fault's mark;
- the state replies the servos sent intact, the samples the recorder received and the rows
  written.

Signals (Ctrl-C, SIGTERM) are sent by the process to itself from the gait at the fault time,
so they land wherever the loop is. A full disk is a file that refuses the sample due at the
fault time (as ``write(2)`` does with ENOSPC), and the sidecar that cannot be replaced then.
The USB adapter's removal (``unplug``) is not in the matrix: the emulator stops with its port,
so the servos' watchdog cannot be observed (a cut bus cable is the same for the servos).

Usage: ``python benchmarks/fault_matrix.py [--cases crc,cut] [--duration 3] [--at 1]``.
"""
from __future__ import annotations

import argparse
import contextlib
import math
import os
import signal
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks._results import write_results  # noqa: E402
from cobra_model.gait import SidewindingGait  # noqa: E402
from cobra_model.run_files import read_run  # noqa: E402
from hardware import control_table as ct  # noqa: E402
from hardware.config import BusConfig  # noqa: E402
from hardware.emulator import EmulatorProcess  # noqa: E402
from hardware.faults import Fault, full_disk_after, parse_fault  # noqa: E402
from hardware.plant import KinematicPlant  # noqa: E402
from hardware.recorder import record_gait  # noqa: E402
from integrators.simulate import simulate_like  # noqa: E402
from sysid.gap.metrics import compare_runs  # noqa: E402

GAIT = SidewindingGait(freq_hz=0.5, ramp_s=0.5)


@dataclass(frozen=True)
class Case:
    """One row: a bus fault (``spec``, at the fault time) or a host fault (``host``)."""

    label: str
    spec: str | None = None
    host: str | None = None  # "sigint", "sigterm" or "disk"


CASES: dict[str, Case] = {
    "crc": Case("CRC error (3 replies)", spec="crc@{at}x3"),
    "drop": Case("dropped replies (3)", spec="drop@{at}x3"),
    "dead": Case("dead servo (ID 5 silent)", spec="silent:5@{at}"),
    "overload": Case("overload bit (ID 3)", spec="overload:3@{at}"),
    "brownout": Case("brownout (ID 2 at 8.5 V)", spec="voltage:2@{at}"),
    "cut": Case("pulled bus cable", spec="cut@{at}"),
    "ctrl_c": Case("Ctrl-C", host="sigint"),
    "sigterm": Case("SIGTERM", host="sigterm"),
    "disk": Case("full disk", host="disk"),
}


class _SignalAt:
    """The gait, sending ``signum`` to this process once at ``at_s`` of recording time."""

    def __init__(self, signum: int, at_s: float) -> None:
        self.signum, self.at_s, self.sent = signum, at_s, False

    def q_ref(self, t: float) -> np.ndarray:
        if t >= self.at_s and not self.sent:
            self.sent = True
            os.kill(os.getpid(), self.signum)
        return GAIT.q_ref(t)

    def to_json(self) -> dict[str, Any]:
        return GAIT.to_json()


def run_case(key: str, case: Case, duration_s: float, at_s: float, workdir: Path) -> dict[str, Any]:
    """Record once with the case's fault; the row of the table."""
    faults: list[Fault] = [parse_fault(case.spec.format(at=at_s))] if case.spec else []
    gait: Any = GAIT
    if case.host in ("sigint", "sigterm"):
        gait = _SignalAt(signal.SIGINT if case.host == "sigint" else signal.SIGTERM, at_s)
    previous_sigint = signal.signal(signal.SIGINT, signal.default_int_handler)
    with EmulatorProcess(KinematicPlant, faults=faults) as emu, contextlib.ExitStack() as host:
        config = BusConfig(port=emu.port)
        if case.host == "disk":
            host.enter_context(full_disk_after(int(round(at_s * config.control_rate_hz))))
        try:
            result = record_gait(config, gait, duration_s=duration_s, out=workdir / f"{key}.csv", settle_s=0.0)
        finally:
            signal.signal(signal.SIGINT, previous_sigint)
        stats = emu.stats()
        torque = [emu.register(i, ct.TORQUE_ENABLE) for i in config.servo_ids]
    # per servo: its torque off after the fault, else its watchdog stop (on the emulator's clock)
    off = {i: stats.torque_off_s[i] for i in config.servo_ids if stats.torque_off_s.get(i, -1.0) >= at_s}
    by_watchdog = [i for i in config.servo_ids if i not in off and i in stats.watchdog_stops_s]
    halted = [*off.values(), *(stats.watchdog_stops_s[i] for i in by_watchdog)]
    if result.status.value == "completed":
        how = "run completed"
    elif len(halted) < len(config.servo_ids):
        how = "not all stopped"
    else:
        how = "torque off" + (f"; watchdog: {', '.join(f'ID {i}' for i in by_watchdog)}" if by_watchdog else "")
        if not off:
            how = "watchdog (all)"
    stop_s = max(halted) - at_s if how not in ("run completed", "not all stopped") else float("nan")
    readable, joint_rmse = False, float("nan")
    if result.path is not None:
        run = read_run(result.path)
        report = compare_runs(run, simulate_like(run))
        readable = True
        joint_rmse = float(np.nanmean(report.joint_rmse))
        rows = run.n_samples
        comm = run.meta.get("comm")
    else:
        rows, comm = 0, None
    sent = stats.intact_sync_reads.get(ct.PRESENT_STATE_ADDRESS, 0) - 1  # less torque_on's read
    received = comm["reads_ok"] - 1 if comm else None
    return {"case": key, "label": case.label, "status": result.status.value, "message": result.message,
            "stopped_by": how, "time_to_stop_s": stop_s, "torque_left_on": [i for i, t in zip(config.servo_ids, torque)
                                                                             if t],
            "run_readable": readable, "compare_joint_rmse_rad": joint_rmse,
            "replies_sent_intact": sent, "samples_received": received, "rows_written": rows,
            "sidecar_updated": comm is not None}


def markdown(rows: list[dict[str, Any]], duration_s: float, at_s: float) -> str:
    """The table."""
    lines = [f"Each run: the paper's gait at 0.5 Hz for {duration_s:g} s on the emulated bus (servos "
             "without dynamics: each joint a first-order lag toward its goal; 50 Hz loop, Bus Watchdog 100 ms), "
             f"the fault at {at_s:g} s after the first torque on.", "",
             "| fault | stop status | servos stopped by | fault -> stopped [ms] | torque left on | run readable, "
             "`cobra compare` joint RMSE [rad] | replies sent intact / received / rows written |",
             "|---|---|---|---:|---|---|---|"]
    for r in rows:
        stop = f"{1e3 * r['time_to_stop_s']:.0f}" if math.isfinite(r["time_to_stop_s"]) else "-"
        left = ", ".join(f"ID {i}" for i in r["torque_left_on"]) or "none"
        readable = (f"yes, {r['compare_joint_rmse_rad']:.4f}" if r["run_readable"] else "no")
        if not r["sidecar_updated"] and r["run_readable"]:
            readable += " (sidecar not updated)"
        received = "-" if r["samples_received"] is None else r["samples_received"]
        lines.append(f"| {r['label']} | {r['status']} | {r['stopped_by']} | {stop} | {left} | {readable} | "
                     f"{r['replies_sent_intact']} / {received} / {r['rows_written']} |")
    lines += ["", "A servo whose torque is left on after a cut cable is held by its watchdog (it stopped where "
              "it was and refuses goals); the emulated dead servo hears nothing (as with a broken wire to "
              "it), so its watchdog stops it; a servo that crashed outright would not. Received minus "
              "written: a sample in flight when the stop came (a signal between receiving and writing) or "
              "refused by the full disk; sent minus received: replies the driver gave up on (retried reads). "
              "The joint RMSE is our simulated servos (the nominal motor, each goal held until the next "
              "sample) against the emulator's lag: the gap between two servo models, not a fault's mark."]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default=",".join(CASES), help=f"comma-separated subset of {', '.join(CASES)}")
    parser.add_argument("--duration", type=float, default=3.0, help="recording length [s] (default 3)")
    parser.add_argument("--at", type=float, default=1.0, help="fault time after the first torque on [s] (default 1)")
    args = parser.parse_args(argv)
    chosen = [c.strip() for c in args.cases.split(",") if c.strip()]
    unknown = [c for c in chosen if c not in CASES]
    if unknown or not chosen:
        parser.error(f"--cases: unknown case(s) {unknown or chosen}; choose from {', '.join(CASES)}")
    if not 0 < args.at < args.duration:
        parser.error(f"--at must lie inside the recording (0, {args.duration:g}) s, got {args.at:g}")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for k, key in enumerate(chosen, 1):
            t0 = time.perf_counter()
            rows.append(run_case(key, CASES[key], args.duration, args.at, Path(tmp)))
            print(f"[{k}/{len(chosen)}] {key}: {rows[-1]['status']} ({time.perf_counter() - t0:.1f} s)",
                  file=sys.stderr, flush=True)
    text = markdown(rows, args.duration, args.at)
    write_results("fault_matrix", rows, {"cases": chosen, "duration_s": args.duration, "fault_at_s": args.at,
                                         "plant": "KinematicPlant", "gait_hz": GAIT.freq_hz}, text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
