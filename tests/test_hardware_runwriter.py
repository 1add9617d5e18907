"""The incremental run writer: same file as ``write_run``, valid at every moment, even after a kill."""
from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from cobra_model.errors import InputError
from cobra_model.run import Run
from cobra_model.run_files import read_run, write_run
from hardware.runwriter import UNFINISHED_NOTE, IncrementalRunWriter, RunWriteError

REPO = Path(__file__).resolve().parent.parent


def _samples(n: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(1)
    return {
        "t": np.cumsum(rng.uniform(0.019, 0.021, n)),
        "q_ref": rng.normal(size=(n, 11)),
        "q": rng.normal(size=(n, 11)),
        "dq": rng.normal(size=(n, 11)),
        "current": rng.normal(size=(n, 11)),
        "latency": rng.uniform(0.001, 0.004, n),
    }


def test_file_is_byte_identical_to_write_run(tmp_path: Path) -> None:
    s = _samples(20)
    writer = IncrementalRunWriter(tmp_path / "inc.csv", {"source": "hardware"})
    for k in range(20):
        writer.append(s["t"][k], s["q_ref"][k], s["q"][k], s["dq"][k], s["current"][k], s["latency"][k])
    writer.close()
    n = len(s["t"])
    reference = Run(t=s["t"], q_ref=s["q_ref"], q=s["q"], dq=s["dq"], current=s["current"],
                    head_pos=np.full((n, 3), np.nan), head_quat=np.full((n, 4), np.nan),
                    extra={"read_latency_s": s["latency"]})
    write_run(reference, tmp_path / "ref.csv")
    assert (tmp_path / "inc.csv").read_bytes() == (tmp_path / "ref.csv").read_bytes()
    run = read_run(tmp_path / "inc.csv")
    assert run.meta == {"format": "cobra-run/1", "source": "hardware"}
    np.testing.assert_array_equal(run.q, s["q"])
    np.testing.assert_array_equal(run.extra["read_latency_s"].astype(float), s["latency"])
    assert np.isnan(run.head_pos).all() and np.isnan(run.head_quat).all()


def test_run_is_valid_while_being_written_and_notes_a_stop(tmp_path: Path) -> None:
    s = _samples(5)
    writer = IncrementalRunWriter(tmp_path / "run.csv", {"source": "emulator", "notes": ["bench test"]})
    for k in range(3):
        writer.append(s["t"][k], s["q_ref"][k], s["q"][k], s["dq"][k], s["current"][k], s["latency"][k])
    during = read_run(tmp_path / "run.csv")
    assert during.n_samples == 3
    assert during.meta["notes"] == ["bench test", UNFINISHED_NOTE]
    writer.close(notes=["partial run: servo 5 stopped answering"], meta={"timing": {"achieved_rate_hz": 49.9}})
    after = read_run(tmp_path / "run.csv")
    assert after.meta["notes"] == ["bench test", "partial run: servo 5 stopped answering"]
    assert after.meta["timing"] == {"achieved_rate_hz": 49.9}
    assert not (tmp_path / "run.json.tmp").exists()


def test_refuses_to_overwrite_unless_forced(tmp_path: Path) -> None:
    (tmp_path / "run.json").write_text("{}")
    with pytest.raises(FileExistsError, match="run.json already exists; pass --force"):
        IncrementalRunWriter(tmp_path / "run.csv", {})
    IncrementalRunWriter(tmp_path / "run.csv", {}, force=True).close()
    with pytest.raises(FileExistsError, match="run.csv already exists"):
        IncrementalRunWriter(tmp_path / "run.csv", {})
    with pytest.raises(InputError, match="must end in .csv"):
        IncrementalRunWriter(tmp_path / "run.txt", {})


def test_samples_survive_a_killed_process(tmp_path: Path) -> None:
    out = tmp_path / "killed.csv"
    script = textwrap.dedent(f"""
        import os, signal
        import numpy as np
        from hardware.runwriter import IncrementalRunWriter
        w = IncrementalRunWriter({str(out)!r}, {{"source": "hardware"}})
        for k in range(40):
            w.append(0.02 * k, np.zeros(11), np.full(11, k), np.zeros(11), np.zeros(11), 0.002)
        os.kill(os.getpid(), signal.SIGKILL)
    """)
    proc = subprocess.run([sys.executable, "-c", script], cwd=REPO, capture_output=True, timeout=60)
    assert proc.returncode == -9, proc.stderr.decode()
    run = read_run(out)
    assert run.n_samples == 40
    np.testing.assert_array_equal(run.q[:, 0], np.arange(40))
    assert json.loads((tmp_path / "killed.json").read_text())["notes"] == [UNFINISHED_NOTE]



def test_a_full_disk_keeps_every_complete_sample_and_the_old_sidecar(tmp_path: Path, full_disk_after) -> None:
    full_disk_after(3)
    writer = IncrementalRunWriter(tmp_path / "full.csv", {"source": "test"})
    zeros = np.zeros(11)
    for k in range(3):
        writer.append(0.02 * k, zeros, zeros, zeros, zeros, 0.002)
    with pytest.raises(RunWriteError, match=r"cannot write sample 4 to .*full\.csv: the disk is full "
                                            r"\(No space left on device\); the file keeps the 3 samples before it"):
        writer.append(0.06, zeros, zeros, zeros, zeros, 0.002)  # 7 bytes of it land, then the disk is full
    writer.close(notes=["partial run: disk full"])
    assert not writer.sidecar_updated and "could not be updated (No space left on device)" in writer.sidecar_error
    run = read_run(tmp_path / "full.csv")  # no half line: still a valid run
    assert run.n_samples == 3 == writer.rows
    assert run.meta["notes"] == [UNFINISHED_NOTE]


def test_the_callers_thread_never_waits_for_a_slow_fsync(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A control loop appends; the device's fsync runs on the writer's own thread, so that a slow
    device (an SD card) cannot stretch the loop past the servos' Bus Watchdog."""
    import os
    import threading
    import time

    import hardware.runwriter as runwriter
    real_fsync = os.fsync
    callers: list[threading.Thread] = []
    release = threading.Event()

    def slow_fsync(fd: int) -> None:
        callers.append(threading.current_thread())
        if threading.current_thread() is not threading.main_thread():
            release.wait(10.0)  # a device that takes its time
        real_fsync(fd)

    writer = IncrementalRunWriter(tmp_path / "slow.csv", {"source": "test"}, fsync_interval_s=0.01)
    monkeypatch.setattr(runwriter.os, "fsync", slow_fsync)
    zeros = np.zeros(11)
    for k in range(5):
        writer.append(0.02 * k, zeros, np.full(11, k), zeros, zeros, 0.002)
        time.sleep(0.03)
    deadline = time.monotonic() + 5.0
    while not callers and time.monotonic() < deadline:
        time.sleep(0.01)
    assert callers and all(c is not threading.main_thread() for c in callers)  # blocked in the writer's thread
    release.set()
    writer.close()
    assert threading.main_thread() in callers  # close syncs the file and the sidecar itself
    run = read_run(tmp_path / "slow.csv")
    assert run.n_samples == 5 == writer.rows
    np.testing.assert_array_equal(run.q[:, 0], np.arange(5))


def test_a_failed_fsync_stops_the_next_append(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import errno
    import os
    import threading
    import time

    import hardware.runwriter as runwriter
    real_fsync = os.fsync

    def failing_fsync(fd: int) -> None:
        if threading.current_thread() is not threading.main_thread():
            raise OSError(errno.EIO, "Input/output error")
        real_fsync(fd)

    writer = IncrementalRunWriter(tmp_path / "eio.csv", {"source": "test"}, fsync_interval_s=0.01)
    monkeypatch.setattr(runwriter.os, "fsync", failing_fsync)
    zeros = np.zeros(11)
    writer.append(0.0, zeros, zeros, zeros, zeros, 0.002)
    deadline = time.monotonic() + 5.0
    while writer._sync_error is None and time.monotonic() < deadline:
        time.sleep(0.01)
    with pytest.raises(RunWriteError, match=r"cannot sync .*eio\.csv to the device \(Input/output error\); "
                                            r"1 samples written"):
        writer.append(0.02, zeros, zeros, zeros, zeros, 0.002)
    writer.close(notes=["partial run: write failed"])
    assert read_run(tmp_path / "eio.csv").n_samples == 1
