"""Build the replay scene in a meshcat viewer: robots, trails, markers, final ball, legend, animation.

Scene graph (paths under ``/meshcat``):

- ``replay`` - everything below, translated by ``-centre`` so that the viewer's camera, which
  orbits the origin, looks at the middle of the motion. meshcat's own grid and axes stay at the
  viewer's origin, so they are hidden and replaced by:
- ``replay/ground`` - a 0.5 m grid on the world's ground (``z = 0``) under the motion, and
- ``replay/world_axes`` - the world frame's axes (x red, y green, z blue, 0.3 m).
- ``replay/runs/<node>/visuals/<geometry>`` - the URDF's visual geometry loaded by Pinocchio's
  :class:`~pinocchio.visualize.MeshcatVisualizer`: URDF colours for the measured run, one
  translucent colour for each simulated run.
- ``replay/runs/<node>/trail`` - the head's path (a line through every valid sample).
- ``replay/runs/<measured>/markers/<body>`` - a sphere per tracked body of the measured run.
- ``replay/final_head`` - a ball at the measured run's last valid head position.
- ``replay/legend`` - a sprite with one coloured row per run (meshcat has no legend widget);
  it keeps its size on screen and is drawn over the scene.

The animation (one meshcat clip per moving node, keyed in seconds since the measured run's
first sample) moves the robots and markers; the browser's Animations panel plays and scrubs it.
"""
from __future__ import annotations

import io
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from PIL import Image, ImageDraw, ImageFont
from pinocchio.visualize import MeshcatVisualizer

from cobra_model import design
from cobra_model.model import CobraModel
from viz._meshcat import animation, meshcat, mg
from viz.tracks import Track, frame_samples

#: Opacity of the simulated robots.
GHOST_OPACITY = 0.35
#: Radius of the tracked-body markers [m]: larger than a module's 0.045 m, translucent, so a
#: marker shows as a halo around its body where mocap and joint angles agree.
MARKER_RADIUS_M = 0.055
#: Radius of the ball at the measured final head position [m] (translucent, larger than the
#: head, so it shows around the measured head when the replay ends).
FINAL_BALL_RADIUS_M = 0.065
#: Half the robot's length [m]: how far the robot reaches from its head or its middle.
HALF_ROBOT_M = 0.5 * design.NUM_MODULES * design.MODULE_PITCH_M
#: Spacing of the ground grid's lines [m].
GRID_SPACING_M = 0.5
#: Background gradient, top and bottom, RGB in [0, 1] (light, like the paper's figures).
BACKGROUND = ((0.98, 0.98, 0.98), (0.80, 0.80, 0.82))
#: Vertical field of view of meshcat's default camera [deg].
CAMERA_FOV_DEG = 75.0
#: Direction from the scene's centre to the default camera, world frame (front-right, above).
CAMERA_DIRECTION = np.array([0.45, -0.75, 0.62]) / np.linalg.norm([0.45, -0.75, 0.62])
#: Height on screen of one legend row, as a fraction of the viewer's height.
LEGEND_ROW_SCREEN_FRACTION = 0.05


@dataclass(frozen=True)
class ReplayScene:
    """What :func:`build_scene` drew.

    Attributes:
        tracks: the runs, measured first.
        frame_times: (F,) animation keyframe times [s since the measured run's first sample];
            ``frame_times[-1]`` is the measured run's duration.
        fps: the frame rate the frames were decimated to [1/s].
        centre: (3,) world point [m] that the scene is centred on (moved to the origin).
        robot_nodes: track node -> meshcat paths, relative to ``/meshcat/replay``, of its
            visual geometries.
    """

    tracks: tuple[Track, ...]
    frame_times: np.ndarray
    fps: float
    centre: np.ndarray
    robot_nodes: dict[str, tuple[str, ...]]

    @property
    def n_frames(self) -> int:
        """Number of animation keyframes F."""
        return int(self.frame_times.size)

    @property
    def duration(self) -> float:
        """Length of the animation [s]."""
        return float(self.frame_times[-1])


def colour_int(rgb: Sequence[float]) -> int:
    """``0xRRGGBB`` of an RGB triple in [0, 1] (three.js colour)."""
    r, g, b = (int(round(255 * min(max(c, 0.0), 1.0))) for c in rgb[:3])
    return (r << 16) | (g << 8) | b


class _SpriteMaterial(mg.GenericMaterial):
    """three.js ``SpriteMaterial`` (meshcat's Python side has no sprite classes)."""

    _type = "SpriteMaterial"


class _Sprite(mg.Object):
    """three.js ``Sprite``: a textured rectangle that always faces the camera."""

    _type = "Sprite"

    def __init__(self, material: _SpriteMaterial):
        super().__init__(mg.Box([1.0, 1.0, 1.0]), material)  # three.js ignores a sprite's geometry


def legend_image(rows: Sequence[tuple[str, tuple[float, float, float], bool]]) -> Image.Image:
    """The legend: per row a swatch in the colour (a ring for translucent runs) and the text.

    Args:
        rows: ``(text, rgb in [0, 1], translucent)`` per row.
    """
    row_px, pad, font = 44, 12, ImageFont.load_default(size=26)
    width = 2 * pad + row_px + max(int(font.getlength(text)) for text, _, _ in rows)
    image = Image.new("RGBA", (width, 2 * pad + row_px * len(rows)), (255, 255, 255, 215))
    draw = ImageDraw.Draw(image)
    for i, (text, rgb, translucent) in enumerate(rows):
        top = pad + i * row_px
        colour = tuple(int(round(255 * c)) for c in rgb)
        box = (pad + 4, top + 6, pad + row_px - 10, top + row_px - 6)
        if translucent:
            draw.ellipse(box, fill=colour + (110,), outline=colour, width=4)
        else:
            draw.ellipse(box, fill=colour)
        draw.text((pad + row_px, top + row_px // 2), text, fill=(20, 20, 20), font=font, anchor="lm")
    return image


def _visual_model(model: CobraModel) -> pin.GeometryModel:
    """The URDF's visual geometry, attached to ``model.pin_model``."""
    urdf = model.urdf_path
    return pin.buildGeomFromUrdf(model.pin_model, str(urdf), pin.GeometryType.VISUAL, None,
                                 [str(urdf.parent)])


def _translation(p: np.ndarray) -> np.ndarray:
    """(4, 4) homogeneous translation by ``p`` (3,) [m]."""
    transform = np.eye(4)
    transform[:3, 3] = p
    return transform


def _scene_extent(tracks: Sequence[Track]) -> tuple[np.ndarray, np.ndarray]:
    """Bounding box ``(lo, hi)`` (3,) each [m] of the heads and tracked bodies, on the ground
    (``z = 0``)."""
    points = np.vstack([p for tr in tracks for p in (tr.head_pos, *tr.bodies.values())])
    lo, hi = points.min(axis=0), points.max(axis=0)
    lo[2] = hi[2] = 0.0
    return lo, hi


def _ground_grid(lo: np.ndarray, hi: np.ndarray, margin: float) -> mg.LineSegments:
    """Grid lines at multiples of :data:`GRID_SPACING_M` covering ``lo..hi`` (x, y) [m] plus
    ``margin`` [m], on ``z = 0`` in the world frame."""
    start = np.floor((lo[:2] - margin) / GRID_SPACING_M) * GRID_SPACING_M
    stop = np.ceil((hi[:2] + margin) / GRID_SPACING_M) * GRID_SPACING_M
    xs = np.arange(start[0], stop[0] + 1e-9, GRID_SPACING_M)
    ys = np.arange(start[1], stop[1] + 1e-9, GRID_SPACING_M)
    ends = [((x, start[1], 0.0), (x, stop[1], 0.0)) for x in xs]
    ends += [((start[0], y, 0.0), (stop[0], y, 0.0)) for y in ys]
    points = np.asarray(ends, dtype=np.float32).reshape(-1, 3).T
    return mg.LineSegments(mg.PointsGeometry(np.ascontiguousarray(points)),
                           mg.LineBasicMaterial(color=0x9A9A9A))


def _camera_basis() -> tuple[np.ndarray, np.ndarray]:
    """The default view's right and up directions (3,) each, world frame."""
    right = np.cross(-CAMERA_DIRECTION, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    return right, np.cross(right, -CAMERA_DIRECTION)


def _set_view(vis: meshcat.Visualizer, radius: float) -> float:
    """Light background, meshcat's grid and axes hidden, the default camera placed to see a disc
    of ``radius`` [m] about the origin; returns the camera's distance to the origin [m]."""
    vis["/Background"].set_property("top_color", list(BACKGROUND[0]))
    vis["/Background"].set_property("bottom_color", list(BACKGROUND[1]))
    for node in ("/Grid", "/Axes"):
        vis[node].set_property("visible", False)
    distance = 0.95 * radius / np.tan(np.deg2rad(CAMERA_FOV_DEG / 2))
    x, y, z = distance * CAMERA_DIRECTION
    # The camera lives in meshcat's y-up "rotated" frame: world (x, y, z) -> (x, z, -y).
    vis["/Cameras/default/rotated/<object>"].set_property("position", [float(x), float(z), float(-y)])
    return float(distance)


def _legend(root: meshcat.Visualizer, tracks: Sequence[Track], centre: np.ndarray, distance: float) -> None:
    """The legend sprite, in the top-left corner of the default view, drawn over everything.

    Args:
        root: the ``replay`` node.
        tracks: the runs, measured first.
        centre: (3,) the world point [m] that ``root`` moves to the origin.
        distance: from the default camera to the origin [m].
    """
    measured = tracks[0]
    drawn_in_red = "trail, markers" if measured.bodies else "trail"
    rows = [(f"{measured.name} (solid; red: {drawn_in_red})", measured.colour, False)]
    rows += [(f"{tr.name} (ghost, trail)", tr.colour, True) for tr in tracks[1:]]
    rows.append(("measured final head position", measured.colour, False))
    image = legend_image(rows)
    width, height = image.size
    png = io.BytesIO()
    image.save(png, format="PNG")
    material = _SpriteMaterial(map=mg.ImageTexture(mg.PngImage(png.getvalue())), transparent=True,
                               depthTest=False, sizeAttenuation=False)
    sprite = root["legend"]
    sprite.set_object(_Sprite(material))
    # Sizes on screen are in normalised device coordinates (the view is 2 units high). With
    # sizeAttenuation off, a sprite of scale s is s / tan(fov / 2) such units high.
    tan_half = np.tan(np.deg2rad(CAMERA_FOV_DEG / 2))
    aspect = 4 / 3  # assumed viewer shape: a wider viewer shows the legend further from the edge
    half_h = LEGEND_ROW_SCREEN_FRACTION * len(rows)
    half_w = half_h * width / height / aspect
    ndc_x, ndc_y = -0.97 + half_w, 0.88 - half_h  # left edge, below the page's caption
    right, up = _camera_basis()
    # A point at the origin's depth moved by (a right + b up) tan(fov / 2) distance appears at
    # NDC (a / aspect, b); the replay root's shift is undone so that it lands there.
    transform = np.diag([2 * half_h * tan_half * width / height, 2 * half_h * tan_half, 1.0, 1.0])
    transform[:3, 3] = centre + distance * tan_half * (ndc_x * aspect * right + ndc_y * up)
    sprite.set_transform(transform)
    sprite.set_property("renderOrder", 10)


def build_scene(vis: meshcat.Visualizer, tracks: Sequence[Track], *, fps: float = 30.0,
                model: CobraModel | None = None) -> ReplayScene:
    """Draw ``tracks`` (measured first) into ``vis`` and start the animation.

    Anything previously under ``/meshcat/replay`` is deleted first.

    Args:
        vis: a meshcat visualizer (a live server's, or one over a recording window).
        tracks: from :func:`viz.tracks.make_tracks`; the first is the measured run.
        fps: animation frame rate [1/s]; the measured run's samples are decimated to it.
        model: the COBRA model whose URDF supplies the geometry (default: the project's URDF).

    Raises:
        InputError: if ``fps`` is not positive.
    """
    measured = tracks[0]
    frame_times = measured.t_rel[frame_samples(measured.run.t, fps)]
    model = model or CobraModel.load()
    visual_model = _visual_model(model)
    lo, hi = _scene_extent(tracks)
    centre = (lo + hi) / 2
    radius = float(np.hypot(*(hi - lo)[:2]) / 2 + HALF_ROBOT_M)  # encloses every robot

    root = vis["replay"]
    root.delete()
    root.set_transform(_translation(-centre))
    distance = _set_view(vis, radius)
    root["ground"].set_object(_ground_grid(lo, hi, margin=HALF_ROBOT_M))
    root["world_axes"].set_object(mg.triad(0.3))

    robot_nodes: dict[str, tuple[str, ...]] = {}
    for tr in tracks:
        viewer = MeshcatVisualizer(model.pin_model, None, visual_model)
        viewer.initViewer(viewer=root)
        viewer.loadViewerModel(rootNodeName=f"runs/{tr.node}",
                               visual_color=[*tr.colour, GHOST_OPACITY] if tr.ghost else None)
        viewer.display(model.configuration(tr.run.q[0], tr.head_pos[0], tr.head_quat[0]))
        robot_nodes[tr.node] = tuple(viewer.getViewerNodeName(g, pin.GeometryType.VISUAL)
                                     for g in visual_model.geometryObjects)
        valid = np.isfinite(tr.run.head_pos).all(axis=1)
        trail = np.ascontiguousarray(tr.run.head_pos[valid].T, dtype=np.float32)
        root[f"runs/{tr.node}/trail"].set_object(
            mg.Line(mg.PointsGeometry(trail), mg.LineBasicMaterial(color=colour_int(tr.colour))))

    marker_material = mg.MeshPhongMaterial(color=colour_int(measured.colour), opacity=0.45)
    for body, pos in measured.bodies.items():
        marker = root[f"runs/{measured.node}/markers/{body}"]
        marker.set_object(mg.Sphere(MARKER_RADIUS_M), marker_material)
        marker.set_transform(_translation(pos[0]))
    ball = root["final_head"]
    ball.set_object(mg.Sphere(FINAL_BALL_RADIUS_M),
                    mg.MeshPhongMaterial(color=colour_int(measured.colour), opacity=0.55))
    ball.set_transform(_translation(measured.final_head_pos))
    _legend(root, tracks, centre, distance)

    vis.set_animation(_animation(root, tracks, frame_times, fps, model, visual_model, robot_nodes),
                      play=True, repetitions=1)
    return ReplayScene(tuple(tracks), frame_times, float(fps), centre, robot_nodes)


def _animation(root: meshcat.Visualizer, tracks: Sequence[Track], frame_times: np.ndarray, fps: float,
               model: CobraModel, visual_model: pin.GeometryModel,
               robot_nodes: dict[str, tuple[str, ...]]) -> animation.Animation:
    """Keyframes at ``frame_times`` [s]: every robot geometry's pose and every marker's position.

    Only position and orientation are animated; a mesh's scale stays as ``display`` set it.
    """
    anim = animation.Animation(default_framerate=fps)
    data, visual_data = model.pin_model.createData(), visual_model.createData()
    samples = {tr.node: tr.samples_at(frame_times) for tr in tracks}
    measured = tracks[0]
    for k, tau in enumerate(frame_times):
        with anim.at_frame(root, float(tau * fps)) as frame:
            for tr in tracks:
                i = samples[tr.node][k]
                q = model.configuration(tr.run.q[i], tr.head_pos[i], tr.head_quat[i])
                pin.forwardKinematics(model.pin_model, data, q)
                pin.updateGeometryPlacements(model.pin_model, data, visual_model, visual_data)
                for g, node in enumerate(robot_nodes[tr.node]):
                    frame[node].set_transform(visual_data.oMg[g].homogeneous)
            i = samples[measured.node][k]
            for body, pos in measured.bodies.items():
                frame[f"runs/{measured.node}/markers/{body}"].set_property(
                    "position", "vector3", [float(v) for v in pos[i]])
    return anim
