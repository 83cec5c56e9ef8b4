"""Meshcat view of a run: the arm, the compliant wall and the contact force.

The arm is drawn by Drake's ``MeshcatVisualizer`` from the SceneGraph
(illustration geometry of ``models/arm3dof.urdf``). What the SceneGraph does
not know, the wall and the force, is drawn by :class:`ContactVisualizer`:

* **Wall.** A box (``wall_size``, m) whose front face, facing the arm (-x),
  sits at world x = ``surface_x + penetration``: it moves with the tip while
  in contact and is at rest (``surface_x``) otherwise (the free surface's
  relaxation after the tip leaves, a few ms at the bundled B_e / K_e, is
  not drawn: ``penetration`` is 0 out of contact). A thin dark strip
  along the wall's top edge marks the rest surface, so the push shows as
  the gap between the strip and the face.
* **Contact force.** An arrow from the tip along world -x (the direction of
  the force the wall applies on the tip), of length ``f * arrow_m_per_n``
  (default 0.01 m per N: a 20 N push draws 20 cm), hidden when f = 0. It
  is drawn above the arm (``arrow_z``) so a top view shows it over link 3.

Both are drawn in world coordinates (x, y in the arm's plane of motion, z up,
m) at ``publish_period``, with ``time_in_recording`` so that a Meshcat
recording captures them alongside the arm. :func:`start_recording` and
:func:`finish_recording` wrap a run: the arm's MeshcatVisualizer and this
system record into the same ``MeshcatAnimation`` at 1 / ``publish_period``
frames per second, and ``Meshcat.StaticHtml()`` writes a standalone HTML
playback (Drake inlines the viewer's JavaScript: no network needed).

``drake-contact run NAME --out DIR --meshcat`` shows a run live;
``--record FILE`` saves the playback (headless; works without a browser).
"""

import dataclasses as dc
import logging
import os
from pathlib import Path

import numpy as np
from pydrake.geometry import (
    Box, Cylinder, Meshcat, MeshcatCone, MeshcatVisualizer, MeshcatVisualizerParams, Rgba)
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.systems.framework import LeafSystem

from drake_contact.diagram import leaf_systems
from drake_contact.errors import ScenarioError


@dc.dataclass
class ContactVisualizerParams:
    """How the wall and the contact force are drawn (SI units, world frame)."""

    # Period (s) of the drawing and of the recording's frames (1 / fps). A
    # power of two: Meshcat files a sample at frame floor(t * fps), and with
    # e.g. 1/25 s rounding (29 * 0.04 * 25 = 28.999...) would drop frames.
    publish_period: float = 1.0 / 32
    # Meshcat path under which the wall and the arrow live.
    prefix: str = "contact"
    # Wall box extent [along x (thickness), along y, along z] (m).
    wall_size: tuple = (0.06, 0.30, 0.16)
    # Height (m) of the wall box's centre; it spans the arm's links (z -0.06 to 0.08).
    wall_center_z: float = 0.02
    # Wall colour, RGBA (a styrofoam-like pale yellow).
    wall_rgba: tuple = (0.95, 0.80, 0.30, 1.0)
    # Width along x and height (m), and colour of the strip marking the rest
    # surface on top of the wall.
    rest_marker_size: tuple = (0.001, 0.002)
    rest_marker_rgba: tuple = (0.15, 0.15, 0.15, 1.0)
    # Arrow length per newton of normal force (m/N).
    arrow_m_per_n: float = 0.01
    # Height (m) at which the arrow is drawn: above link 3's top (0.08 m in
    # the URDF), which it would otherwise hide in, lying along -x too.
    arrow_z: float = 0.1
    # Shaft radius, head radius (m) and head's share of the arrow's length.
    arrow_shaft_radius: float = 0.004
    arrow_head_radius: float = 0.01
    arrow_head_fraction: float = 0.15
    arrow_rgba: tuple = (0.10, 0.75, 0.20, 1.0)
    # Camera (world, m): a near top-down view of the plane of motion, from
    # far with a narrow vertical field of view (deg) to keep perspective
    # small. The -y offset fixes the image's "up" to +y (Meshcat keeps z up).
    camera_position: tuple = (0.22, -0.1, 1.6)
    camera_target: tuple = (0.22, 0.0, 0.0)
    camera_fov_deg: float = 26.0
    set_camera: bool = True


# Smallest arrow scale drawn (m); a zero scale makes three.js's matrices singular.
_MIN_ARROW_SCALE = 1e-4


class ContactVisualizer(LeafSystem):
    """Draws the compliant wall and the contact force in Meshcat.

    Input ports:
      tip_state (6): tip [x, y, phi, xdot, ydot, phidot] in world (m, rad, /s);
        only x, y are used.
      penetration (1): surface displacement xe (m), 0 out of contact.
      contact_force (1): normal force f >= 0 the wall applies (N).
    No outputs, no state: a periodic publish (``publish_period``) sets the
    Meshcat transforms, with the context time as ``time_in_recording``.

    Meshcat paths (under ``/<prefix>``): ``wall`` (origin on the front face,
    at x = surface_x + xe, y = 0, z = 0), ``wall_rest`` (fixed strip whose
    front edge is at surface_x, on the wall's top),
    ``force`` (origin at the tip at height ``arrow_z``, local +z along world
    -x) whose child ``force/arrow`` is scaled along z by the arrow's length
    (a unit-length cylinder plus cone).
    """

    def __init__(self, meshcat: Meshcat, surface_x: float,
                 params: ContactVisualizerParams | None = None):
        super().__init__()
        self._meshcat = meshcat
        self._surface_x = float(surface_x)
        self._params = params = params or ContactVisualizerParams()
        if not params.publish_period > 0:
            raise ScenarioError(
                f"publish_period = {params.publish_period} is out of range: must be > 0 s")
        root = "/" + params.prefix.strip("/")
        self._paths = {name: f"{root}/{name}" for name in
                       ("wall", "wall/box", "wall_rest", "force", "force/arrow",
                        "force/arrow/shaft", "force/arrow/head")}
        self._tip = self.DeclareVectorInputPort("tip_state", 6)
        self._penetration = self.DeclareVectorInputPort("penetration", 1)
        self._force = self.DeclareVectorInputPort("contact_force", 1)
        self.DeclareInitializationPublishEvent(self._initialize)
        self.DeclarePeriodicPublishEvent(params.publish_period, 0.0, self._draw)
        self.DeclareForcedPublishEvent(self._draw)

    @property
    def params(self) -> ContactVisualizerParams:
        return self._params

    def _initialize(self, context):
        """Sends the (static) geometry, then the first frame."""
        p, m, path = self._params, self._meshcat, self._paths
        thickness, width, height = p.wall_size
        m.SetObject(path["wall/box"], Box(thickness, width, height), Rgba(*p.wall_rgba))
        m.SetTransform(path["wall/box"], RigidTransform([thickness / 2, 0.0, p.wall_center_z]))
        marker_x, marker_z = p.rest_marker_size
        m.SetObject(path["wall_rest"], Box(marker_x, width, marker_z), Rgba(*p.rest_marker_rgba))
        m.SetTransform(path["wall_rest"], RigidTransform(
            [self._surface_x + marker_x / 2, 0.0, p.wall_center_z + (height + marker_z) / 2]))
        # A unit-length arrow along +z; its parent's z scale is the length.
        head = p.arrow_head_fraction
        m.SetObject(path["force/arrow/shaft"], Cylinder(p.arrow_shaft_radius, 1.0 - head),
                    Rgba(*p.arrow_rgba))
        m.SetTransform(path["force/arrow/shaft"], RigidTransform([0.0, 0.0, (1.0 - head) / 2]))
        # The cone's apex is at its origin, opening along +z: flip it so the
        # apex is at the arrow's far end (z = 1).
        m.SetObject(path["force/arrow/head"],
                    MeshcatCone(head, p.arrow_head_radius, p.arrow_head_radius),
                    Rgba(*p.arrow_rgba))
        m.SetTransform(path["force/arrow/head"],
                       RigidTransform(RollPitchYaw(np.pi, 0.0, 0.0), [0.0, 0.0, 1.0]))
        if p.set_camera:
            m.SetCamera(Meshcat.PerspectiveCamera(fov=p.camera_fov_deg))
            m.SetCameraPose(np.asarray(p.camera_position, float),
                            np.asarray(p.camera_target, float))
        # The first frame also live, so a static snapshot shows it even when
        # a recording does not send its frames.
        self._set_frame(context, None)
        self._draw(context)

    def _draw(self, context):
        self._set_frame(context, context.get_time())

    def _set_frame(self, context, time_in_recording):
        p, m, path = self._params, self._meshcat, self._paths
        x, y = self._tip.Eval(context)[0:2]
        xe = float(self._penetration.Eval(context)[0])
        f = float(self._force.Eval(context)[0])
        m.SetTransform(path["wall"], RigidTransform([self._surface_x + xe, 0.0, 0.0]),
                       time_in_recording)
        # Local +z along world -x: a -90 degree turn about y.
        m.SetTransform(path["force"],
                       RigidTransform(RollPitchYaw(0.0, -np.pi / 2, 0.0), [x, y, p.arrow_z]),
                       time_in_recording)
        length = max(f * p.arrow_m_per_n, _MIN_ARROW_SCALE)
        m.SetProperty(path["force/arrow"], "scale", [1.0, 1.0, length], time_in_recording)
        m.SetProperty(path["force"], "visible", bool(f > 0.0), time_in_recording)


def AddContactVisualization(builder, station, meshcat: Meshcat, *,
                            params: ContactVisualizerParams | None = None):
    """Adds the arm's MeshcatVisualizer (on the station's ``query_object``)
    and a :class:`ContactVisualizer` wired to its true tip state,
    penetration and contact force; both publish at ``params.publish_period``.
    ``station`` is a ContactStation already in ``builder``. Returns
    (meshcat_visualizer, contact_visualizer)."""
    params = params or ContactVisualizerParams()
    arm = MeshcatVisualizer.AddToBuilder(
        builder, station.GetOutputPort("query_object"), meshcat,
        MeshcatVisualizerParams(publish_period=params.publish_period))
    contact = builder.AddNamedSystem(
        "contact_visualizer",
        ContactVisualizer(meshcat, station.scenario.environment.surface_x, params))
    for port, signal in (("tip_state", "tip_state_true"), ("penetration", "penetration_true"),
                         ("contact_force", "contact_force_true")):
        builder.Connect(station.GetOutputPort(signal), contact.GetInputPort(port))
    return arm, contact


def new_meshcat() -> Meshcat:
    """A Meshcat server (http://localhost:7000 or the next free port),
    created without Drake's log line; print ``web_url()`` to show it."""
    logger = logging.getLogger("drake")
    level = logger.level
    logger.setLevel(logging.WARNING)
    try:
        return Meshcat()
    finally:
        logger.setLevel(level)


def check_record_path(path) -> Path:
    """Returns ``path`` as a Path once its folder exists (created if needed)
    and is writable; raises ScenarioError naming ``record`` otherwise.
    Called before simulating, so a bad path fails fast."""
    path = Path(path)

    def bad(why):
        raise ScenarioError(f"record = '{path}' is not writable: {why}")
    if path.is_dir():
        bad("it is a folder; give an .html file name")
    for folder in (path.parent, *path.parent.parents):
        if folder.exists():
            if not folder.is_dir():
                bad(f"'{folder}' is a file, not a folder")
            break
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        bad(f"cannot create its folder ({e.strerror or e})")
    if not os.access(path.parent, os.W_OK) or (path.exists() and not os.access(path, os.W_OK)):
        bad("permission denied")
    return path


def start_recording(diagram, *, live: bool):
    """Starts recording every MeshcatVisualizer in ``diagram`` (and with it
    the ContactVisualizer, which draws into the same Meshcat). ``live``:
    also send each frame to connected browsers while recording. Returns the
    MeshcatVisualizers (none if the diagram has no Meshcat)."""
    visualizers = [s for s in leaf_systems(diagram) if isinstance(s, MeshcatVisualizer)]
    for visualizer in visualizers:
        visualizer.DeleteRecording()  # a reused Meshcat: drop an earlier run's frames
        visualizer.StartRecording(set_transforms_while_recording=live)
    return visualizers


def finish_recording(visualizers, meshcat: Meshcat, html_path=None):
    """Stops the recording, sends it to Meshcat (a connected browser can
    replay it) and, given ``html_path``, writes the standalone HTML playback.
    The playback runs once and holds its last frame."""
    if not visualizers:
        return
    for visualizer in visualizers:
        visualizer.StopRecording()
    animation = meshcat.get_mutable_recording()
    animation.set_loop_mode(animation.LoopMode.kLoopOnce)
    animation.set_clamp_when_finished(True)
    visualizers[0].PublishRecording()
    if html_path is not None:
        Path(html_path).write_text(meshcat.StaticHtml(), encoding="utf-8")
