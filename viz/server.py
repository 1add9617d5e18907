"""A meshcat server that only listens on 127.0.0.1, run as a child process.

``meshcat.Visualizer(zmq_url=None)`` starts ``meshcat.servers.zmqserver``, whose ZeroMQ socket
binds 127.0.0.1 but whose web server calls tornado's ``listen(port)`` without an address, i.e. on
every interface, and the server has no option to change that. :class:`LoopbackBridge` is
meshcat's bridge with the web server bound to 127.0.0.1 too; ``python -m viz.server`` runs it and
prints ``zmq_url=...`` and ``web_url=...`` as meshcat's server does, and :class:`MeshcatServer`
starts that process, connects a :class:`meshcat.Visualizer` to it and stops it again. The server
also stops by itself when the process that started it is gone (killed without a chance to stop
it), so no server outlives its replay.
"""
from __future__ import annotations

import contextlib
import io
import os
import subprocess
import sys
import tempfile
from types import TracebackType

from viz._meshcat import meshcat  # first: a missing meshcat raises the install hint

from meshcat.servers.zmqserver import ZMQWebSocketBridge
from tornado.ioloop import PeriodicCallback
from tornado.web import Application

#: The only interface the replay server listens on.
LOOPBACK = "127.0.0.1"
#: How often the server checks that the process that started it is still there [s].
PARENT_CHECK_PERIOD_S = 1.0


class LoopbackBridge(ZMQWebSocketBridge):
    """meshcat's ZeroMQ-to-WebSocket bridge with its web server bound to :data:`LOOPBACK` only."""

    def __init__(self) -> None:
        super().__init__(host=LOOPBACK)

    def make_app(self) -> Application:
        """meshcat's tornado application, whose ``listen`` binds :data:`LOOPBACK`.

        The bridge's constructor calls ``app.listen(port)`` (trying ports from 7000 up), so the
        address is bound into that one method.
        """
        app = super().make_app()
        listen = app.listen
        app.listen = lambda port, **kwargs: listen(port, address=LOOPBACK, **kwargs)
        return app


class MeshcatServer:
    """A :class:`LoopbackBridge` in a child process; a context manager that stops it on exit.

    Attributes:
        zmq_url: where meshcat clients send commands (``tcp://127.0.0.1:<port>``).
        web_url: the viewer page (``http://127.0.0.1:<port>/static/``).
    """

    def __init__(self) -> None:
        self._stderr = tempfile.TemporaryFile()
        self._proc = subprocess.Popen([sys.executable, "-u", "-m", "viz.server"], stdout=subprocess.PIPE,
                                      stderr=self._stderr, stdin=subprocess.DEVNULL, start_new_session=True)
        try:
            self.zmq_url = self._read_value("zmq_url")
            self.web_url = self._read_value("web_url")
        except BaseException:
            self.close()
            raise

    def _read_value(self, key: str) -> str:
        assert self._proc.stdout is not None
        line = self._proc.stdout.readline().decode("utf-8").strip()
        if not line.startswith(f"{key}="):
            with contextlib.suppress(subprocess.TimeoutExpired):
                self._proc.wait(timeout=5)
            self._stderr.seek(0)
            detail = self._stderr.read().decode("utf-8", "replace").strip().splitlines()
            raise RuntimeError(f"the meshcat server (python -m viz.server) did not start "
                               f"(exit code {self._proc.returncode}): {detail[-1] if detail else line!r}")
        return line.split("=", 1)[1]

    def visualizer(self) -> meshcat.Visualizer:
        """A meshcat visualizer connected to this server (meshcat's connection banner suppressed)."""
        with contextlib.redirect_stdout(io.StringIO()):
            return meshcat.Visualizer(zmq_url=self.zmq_url)

    def close(self) -> None:
        """Stop the server process (idempotent)."""
        if self._proc.poll() is None:
            self._proc.terminate()
            try:
                self._proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait()
        if self._proc.stdout is not None:
            self._proc.stdout.close()
        self._stderr.close()

    def __enter__(self) -> MeshcatServer:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()


def main() -> None:
    """Serve until interrupted or orphaned; print the two URLs first (what :class:`MeshcatServer` reads)."""
    bridge = LoopbackBridge()
    parent = os.getppid()

    def stop_if_orphaned() -> None:
        if os.getppid() != parent:  # re-parented: the replay that started us has died
            bridge.ioloop.stop()

    PeriodicCallback(stop_if_orphaned, 1000 * PARENT_CHECK_PERIOD_S).start()
    print(f"zmq_url={bridge.zmq_url}", flush=True)
    print(f"web_url={bridge.web_url}", flush=True)
    with contextlib.suppress(KeyboardInterrupt):
        bridge.run()


if __name__ == "__main__":
    main()
