"""Replay a measured run beside simulated ones in meshcat: a static HTML file or a live server.

The measured run is the solid robot (its joint angles and motion-capture head pose; its other
tracked bodies as markers), every other run a translucent ghost in its own colour; head trails,
a ball at the measured final head position and a legend complete the scene (see
:mod:`viz.scene`). Runs are aligned on their first samples and the animation lasts as long as
the measured run; mocap gaps hold the last valid pose (see :mod:`viz.tracks`).

meshcat is imported only when a replay is made; without it these functions raise an
``ImportError`` that says ``pip install meshcat``.
"""
from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cobra_model.model import CobraModel
from cobra_model.run import Run
from viz.tracks import make_tracks

if TYPE_CHECKING:
    from viz.scene import ReplayScene

#: Default animation frame rate [1/s].
DEFAULT_FPS = 30.0


def record_replay(measured: Run, others: Sequence[tuple[str, Run]], *, fps: float = DEFAULT_FPS,
                  model: CobraModel | None = None) -> tuple[ReplayScene, list[dict[str, Any]]]:
    """Build the replay scene without a server: what was drawn and the meshcat commands.

    Args:
        measured: the reference run (solid robot).
        others: ``(legend name, run)`` per run to compare (ghosts), e.g. simulated reproductions.
        fps: animation frame rate [1/s]; the measured run's samples are decimated to it.
        model: the COBRA model whose URDF gives the geometry (default: the project's URDF).

    Raises:
        InputError: a run without any head pose, or ``fps`` not positive.
        ImportError: meshcat is not installed.
    """
    from viz._meshcat import meshcat
    from viz.html import RecordingWindow
    from viz.scene import build_scene

    window = RecordingWindow()
    scene = build_scene(meshcat.Visualizer(window=window), make_tracks(measured, others), fps=fps,
                        model=model)
    return scene, window.commands


def write_replay_html(measured: Run, others: Sequence[tuple[str, Run]], out: Path, *,
                      fps: float = DEFAULT_FPS) -> Path:
    """Write the replay as one self-contained HTML file (works offline); returns ``out``.

    The page embeds meshcat's viewer (0.85 MB) and the whole animation (about 0.04 MB per robot
    and second of run at 30 frames/s: 2.1 MB for 10 s of three robots); the Animations panel of
    its controls plays and scrubs it. An existing ``out`` is overwritten.

    Args:
        measured: the reference run (solid robot).
        others: ``(legend name, run)`` per run to compare (ghosts).
        out: the HTML file to write.
        fps: animation frame rate [1/s].

    Raises:
        InputError: a run without any head pose, or ``fps`` not positive.
        ImportError: meshcat is not installed.
    """
    from viz.html import static_html

    scene, commands = record_replay(measured, others, fps=fps)
    names = [tr.name for tr in scene.tracks]
    caption = (f"{names[0]}" + (f" vs {', '.join(names[1:])}" if names[1:] else "")
               + f" - {scene.duration:.2f} s; Open Controls > Animations: play, pause, scrub")
    out = Path(out)
    out.write_text(static_html(commands, title=f"COBRA replay - {names[0]}", caption=caption),
                   encoding="utf-8")
    return out


@contextmanager
def serve_replay(measured: Run, others: Sequence[tuple[str, Run]], *,
                 fps: float = DEFAULT_FPS) -> Iterator[tuple[str, ReplayScene]]:
    """Show the replay from a meshcat server on 127.0.0.1 while the ``with`` block runs.

    Yields ``(url, scene)``: the viewer's address and what was drawn. A browser that opens the
    URL later still gets the whole scene and animation. The server stops when the block ends.

    Raises:
        InputError: a run without any head pose, or ``fps`` not positive.
        ImportError: meshcat is not installed.
        RuntimeError: the server process did not start.
    """
    from viz.scene import build_scene
    from viz.server import MeshcatServer

    tracks = make_tracks(measured, others)
    with MeshcatServer() as server:
        yield server.web_url, build_scene(server.visualizer(), tracks, fps=fps)
