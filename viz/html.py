"""Record meshcat commands without a server and write them as one self-contained HTML file.

meshcat's own ``Visualizer.static_html()`` asks a running server for its scene. A replay does
not need a server: :class:`RecordingWindow` stands in for meshcat's window and keeps every
command, and :func:`static_html` embeds meshcat's viewer script (``main.min.js``) and the
commands (msgpack, base64) in one page that replays them when it loads. The page fetches
nothing: it works offline and from ``file://``.
"""
from __future__ import annotations

import base64
import html
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Protocol

import umsgpack

from viz._meshcat import meshcat

#: meshcat's bundled viewer (three.js and the command handler), embedded in every page.
VIEWER_SCRIPT = Path(meshcat.__file__).parent / "viewer" / "dist" / "main.min.js"


class _Command(Protocol):
    def lower(self) -> dict[str, Any]: ...


class RecordingWindow:
    """A meshcat window that keeps the commands instead of sending them to a server.

    Use as ``meshcat.Visualizer(window=RecordingWindow())``. Every ``set_object``,
    ``set_transform``, ``set_property``, ``set_animation`` and ``delete`` lands in
    :attr:`commands`, in order, as the message dict meshcat would send.
    """

    def __init__(self) -> None:
        self.commands: list[dict[str, Any]] = []

    def send(self, command: _Command) -> None:
        """Record one meshcat command."""
        self.commands.append(command.lower())


def static_html(commands: Sequence[dict[str, Any]], *, title: str, caption: str = "") -> str:
    """A standalone HTML page that shows the scene the ``commands`` build.

    Numbers are packed as 32-bit floats (sub-micrometre at the scale of a run) to halve the size.

    Args:
        commands: meshcat command dicts, e.g. :attr:`RecordingWindow.commands`.
        title: the page title.
        caption: a line of text shown over the top-left corner of the viewer.
    """
    packed = [base64.b64encode(umsgpack.packb(c, force_float_precision="single")).decode("ascii")
              for c in commands]
    return _PAGE.format(title=html.escape(title), caption=html.escape(caption),
                        viewer=VIEWER_SCRIPT.read_text(encoding="utf-8"),
                        commands=json.dumps(packed))


_PAGE = """<!DOCTYPE html>
<html>
<head>
<meta charset="utf-8">
<title>{title}</title>
<style>
  body {{ margin: 0; }}
  #meshcat-pane {{ width: 100vw; height: 100vh; overflow: hidden; }}
  #caption {{ position: absolute; left: 8px; top: 6px; font: 13px sans-serif; color: #222;
             background: rgba(255, 255, 255, 0.75); padding: 2px 6px; pointer-events: none;
             max-width: calc(100vw - 270px); }}
</style>
</head>
<body>
<div id="meshcat-pane"></div>
<div id="caption">{caption}</div>
<script>
{viewer}
</script>
<script>
var viewer = new MeshCat.Viewer(document.getElementById("meshcat-pane"));
for (const encoded of {commands}) {{
  const raw = atob(encoded);
  const bytes = new Uint8Array(raw.length);
  for (let i = 0; i < raw.length; i++) bytes[i] = raw.charCodeAt(i);
  viewer.handle_command_bytearray(bytes);
}}
</script>
</body>
</html>
"""
