"""Meshcat view: the ContactVisualizer alone, a recorded run's standalone
HTML (decoded and compared with the run's log), a headless-Chromium
screenshot of it, and ``drake-contact run --record``."""

import base64
import re
import shutil
import struct
import subprocess

import matplotlib.image
import numpy as np
import pytest
from pydrake.geometry import MeshcatVisualizer

from conftest import needs_tool
from drake_contact.app.cli import main
from drake_contact.diagram import MakeContactDiagram, leaf_systems
from drake_contact.simulation import MakeRunDiagram, simulate_scenario
from drake_contact.scenario import load_scenario
from drake_contact.visualization import ContactVisualizer, ContactVisualizerParams, new_meshcat

#: One worker runs this module and its fixture is session-scoped, so the fixture
#: runs once (-n auto; docs/developer/testing.md, "Shared runs").
pytestmark = pytest.mark.xdist_group("test_visualization")

PARAMS = ContactVisualizerParams()
FPS = 1.0 / PARAMS.publish_period
ARM = "/drake/visualizer/kiguchi_arm"


# --- The HTML's Meshcat commands: base64 msgpack, decoded here (no msgpack
# dependency; only the types Meshcat sends).

def _unpack(b, i):
    c = b[i]
    i += 1
    if c <= 0x7f:
        return c, i
    if c >= 0xe0:
        return c - 0x100, i
    if 0x80 <= c <= 0x8f:
        return _pairs(b, i, c & 0x0f)
    if 0x90 <= c <= 0x9f:
        return _items(b, i, c & 0x0f)
    if 0xa0 <= c <= 0xbf:
        return b[i:i + (c & 0x1f)].decode(), i + (c & 0x1f)
    if c in (0xc0, 0xc2, 0xc3):
        return {0xc0: None, 0xc2: False, 0xc3: True}[c], i
    fixed = {0xca: ">f", 0xcb: ">d", 0xcc: ">B", 0xcd: ">H", 0xce: ">I", 0xcf: ">Q",
             0xd0: ">b", 0xd1: ">h", 0xd2: ">i", 0xd3: ">q"}
    if c in fixed:
        return struct.unpack_from(fixed[c], b, i)[0], i + struct.calcsize(fixed[c])
    if 0xd4 <= c <= 0xd8:  # fixext: a type byte and 1-16 bytes
        n = 1 << (c - 0xd4)
        return bytes(b[i + 1:i + 1 + n]), i + 1 + n
    length_bytes = {0xc4: 1, 0xc5: 2, 0xc6: 4, 0xc7: 1, 0xc8: 2, 0xc9: 4, 0xd9: 1, 0xda: 2,
                    0xdb: 4, 0xdc: 2, 0xdd: 4, 0xde: 2, 0xdf: 4}[c]
    n = int.from_bytes(b[i:i + length_bytes], "big")
    i += length_bytes
    if c in (0xdc, 0xdd):
        return _items(b, i, n)
    if c in (0xde, 0xdf):
        return _pairs(b, i, n)
    if c in (0xd9, 0xda, 0xdb):
        return b[i:i + n].decode(), i + n
    if c in (0xc7, 0xc8, 0xc9):  # ext: a type byte, then the data
        return bytes(b[i + 1:i + 1 + n]), i + 1 + n
    return bytes(b[i:i + n]), i + n


def _items(b, i, n):
    out = []
    for _ in range(n):
        value, i = _unpack(b, i)
        out.append(value)
    return out, i


def _pairs(b, i, n):
    out = {}
    for _ in range(n):
        key, i = _unpack(b, i)
        out[key], i = _unpack(b, i)
    return out, i


def meshcat_commands(html):
    commands = []
    for data in re.findall(r"data:application/octet-binary;base64,([A-Za-z0-9+/=]+)", html):
        raw = base64.b64decode(data)
        command, end = _unpack(raw, 0)
        assert end == len(raw)
        commands.append(command)
    return commands


def animation_tracks(commands):
    """{(path, property): (frames, values)} of the one set_animation."""
    (animation,) = [c for c in commands if c["type"] == "set_animation"]
    tracks = {}
    for entry in animation["animations"]:
        assert entry["clip"]["fps"] == FPS
        for track in entry["clip"]["tracks"]:
            frames = np.array([k["time"] for k in track["keys"]])
            values = np.array([k["value"] for k in track["keys"]])
            tracks[entry["path"], track["name"].lstrip(".")] = (frames, values)
    return animation, tracks


# --- The visualizer alone.

def test_contact_visualizer_draws_the_wall_at_the_surface_and_the_force_as_an_arrow():
    meshcat = new_meshcat()
    surface_x = 0.456
    visualizer = ContactVisualizer(meshcat, surface_x)
    context = visualizer.CreateDefaultContext()
    tip = visualizer.GetInputPort("tip_state")
    penetration = visualizer.GetInputPort("penetration")
    force = visualizer.GetInputPort("contact_force")
    meshcat.StartRecording(FPS, False)
    # In contact at 0.5 s: 3 mm in, 21 N; out of contact at 1 s.
    for t, x, xe, f in ((0.5, 0.459, 0.003, 21.0), (1.0, 0.45, 0.0, 0.0)):
        context.SetTime(t)
        tip.FixValue(context, [x, 0.002, 0.0, 0.0, 0.0, 0.0])
        penetration.FixValue(context, [xe])
        force.FixValue(context, [f])
        if t == 0.5:
            visualizer.ExecuteInitializationEvents(context)
        visualizer.ForcedPublish(context)
    meshcat.StopRecording()
    meshcat.PublishRecording()
    commands = meshcat_commands(meshcat.StaticHtml())
    drawn = {c["path"] for c in commands if c["type"] == "set_object"}
    assert {"/contact/wall/box", "/contact/wall_rest", "/contact/force/arrow/shaft",
            "/contact/force/arrow/head"} <= drawn
    _, tracks = animation_tracks(commands)
    frames, wall = tracks["/contact/wall", "position"]
    assert list(frames) == [16, 32]  # 0.5 s and 1 s at 32 fps
    np.testing.assert_allclose(wall, [[0.459, 0, 0], [0.456, 0, 0]], atol=1e-12)
    _, origin = tracks["/contact/force", "position"]
    np.testing.assert_allclose(origin[0], [0.459, 0.002, PARAMS.arrow_z], atol=1e-12)
    _, quaternion = tracks["/contact/force", "quaternion"]  # x, y, z, w: local z along -x
    np.testing.assert_allclose(np.abs(quaternion[0]), [0, np.sqrt(0.5), 0, np.sqrt(0.5)])
    _, scale = tracks["/contact/force/arrow", "scale"]
    assert scale[0, 2] == pytest.approx(21.0 * PARAMS.arrow_m_per_n)  # 0.21 m
    _, visible = tracks["/contact/force", "visible"]
    assert list(visible) == [True, False]


def test_no_visualizer_is_added_without_meshcat():
    scenario = load_scenario("push_constant")

    def systems(diagram):
        return {type(s) for s in leaf_systems(diagram)}
    drawing = {MeshcatVisualizer, ContactVisualizer}
    assert not drawing & systems(MakeContactDiagram(scenario))
    assert not drawing & systems(MakeRunDiagram(scenario)[0])
    assert drawing <= systems(MakeRunDiagram(scenario, meshcat=new_meshcat())[0])


# --- A recorded run.

@pytest.fixture(scope="session")
def recorded(tmp_path_factory):
    # Pushing from the start, push_constant touches at 0.046 s and settles at
    # about 17 N by 0.5 s.
    scenario = load_scenario("push_constant", ["controller.push.start_time=0"], duration=1.5)
    html_path = tmp_path_factory.mktemp("playback") / "push_constant.html"
    result = simulate_scenario(scenario, record=html_path)
    assert result.status == "completed", result.message
    return scenario, result.log, html_path


def test_recording_is_self_contained(recorded):
    _, _, html_path = recorded
    html = html_path.read_text()
    assert html.lstrip().lower().startswith("<!doctype html") or "<html" in html[:500].lower()
    # Nothing loaded from the network: no external script, stylesheet or module.
    assert not re.search(r"""<(script|link|img)[^>]*(src|href)\s*=\s*["']?(https?:)?//""",
                         html, re.IGNORECASE)
    assert not re.search(r"""import[^;'"]*from\s*["'](https?:)?//""", html)
    assert len(re.findall(r"<script", html)) >= 1 and len(html) > 500_000  # viewer inlined


def test_recording_animates_the_arm_the_wall_and_the_force_as_logged(recorded):
    scenario, log, html_path = recorded
    animation, tracks = animation_tracks(meshcat_commands(html_path.read_text()))
    assert animation["options"]["clampWhenFinished"] is True
    n_frames = int(round(scenario.simulation.duration * FPS)) + 1  # 0 to 1.5 s at 32 fps

    # The arm: every link animated on every frame; link 3 follows the tip.
    for link in ("link1", "link2", "link3"):
        frames, _ = tracks[f"{ARM}/{link}", "position"]
        assert list(frames) == list(range(n_frames))

    # The log's sample at t is taken before the plant's step at t, so a
    # frame at 31.25 ms shows the state the 32 ms sample logs.
    frames, wall = tracks["/contact/wall", "position"]
    assert list(frames) == list(range(n_frames))
    rows = np.ceil(frames / FPS / 1e-3 - 1e-9).astype(int)
    xe = log["penetration_true"][rows]
    f = log["contact_force_true"][rows]
    np.testing.assert_allclose(wall[:, 0], scenario.environment.surface_x + xe, atol=1e-12)
    assert wall[0, 0] == scenario.environment.surface_x
    assert np.ptp(wall[:, 0]) > 2e-3  # the surface is pushed in by millimetres

    _, scale = tracks["/contact/force/arrow", "scale"]
    np.testing.assert_allclose(scale[:, 2], np.maximum(f * PARAMS.arrow_m_per_n, 1e-4),
                               atol=1e-12)
    _, visible = tracks["/contact/force", "visible"]
    assert list(visible) == list(f > 0)
    assert not visible[0] and visible[-1]
    _, origin = tracks["/contact/force", "position"]
    np.testing.assert_allclose(origin[:, :2], log["tip_pose_true"][rows, :2], atol=1e-12)


def test_a_recorded_run_is_the_same_run(recorded):
    scenario, log, _ = recorded
    result = simulate_scenario(scenario)
    plain = result.log
    assert result.status == "completed" and plain.keys() == log.keys()
    for key in plain:
        np.testing.assert_array_equal(plain[key], log[key], err_msg=key)


# --- The playback in a browser.

CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--use-angle=swiftshader",
                  "--enable-unsafe-swiftshader", "--hide-scrollbars", "--no-first-run",
                  "--window-size=800,600", "--virtual-time-budget=5000")


def screenshot(html_path, png_path, profile):
    """Renders the playback's last frame (it plays once, 1.5 s, and holds)."""
    needs_tool("chromium", "the Meshcat playback rendered in a browser")
    chromium = shutil.which("chromium")
    subprocess.run([chromium, *CHROMIUM_FLAGS, f"--user-data-dir={profile}",
                    f"--screenshot={png_path}", html_path.as_uri()],
                   check=True, capture_output=True, timeout=120)
    return matplotlib.image.imread(png_path)[..., :3]


def test_headless_chromium_draws_the_arm_the_wall_and_the_arrow(recorded, tmp_path):
    _, _, html_path = recorded
    image = screenshot(html_path, tmp_path / "playback.png", tmp_path / "profile")
    assert image.shape == (600, 800, 3)
    image = image[30:]  # below the "Open Controls" button
    r, g, b = image[..., 0], image[..., 1], image[..., 2]
    background = np.median(image.reshape(-1, 3), axis=0)
    drawn = np.abs(image - background).sum(axis=-1) > 0.15
    spread = image.max(axis=-1) - image.min(axis=-1)
    classes = {
        # Links 1 and 2 (URDF "alu", 0.75 0.75 0.8): light and grey.
        "arm": (image.min(axis=-1) > 0.7) & (spread < 0.1),
        "wall": (r > 0.8) & (g > 0.7) & (r - b > 0.3),  # pale yellow
        "arrow": (g > 0.6) & (g - r > 0.2) & (g - b > 0.3),  # green
    }
    counts = {name: int(mask.sum()) for name, mask in classes.items()}
    print(f"drawn {drawn.mean():.3f} of the pixels; {counts}")
    assert 0.03 < drawn.mean() < 0.5
    # At about 800 px per m: link 1 and 2 cover some 11,000 px, the wall's top
    # 11,000, the 17 N arrow (17 cm by 8 mm) about 1,000.
    assert counts["arm"] > 5000 and counts["wall"] > 5000 and counts["arrow"] > 400
    # Left to right: the arm, the arrow (on the tip), the wall.
    columns = {name: np.nonzero(mask)[1].mean() for name, mask in classes.items()}
    assert columns["arm"] < columns["arrow"] < columns["wall"]


# --- The command line.

def test_cli_record_writes_the_playback(tmp_path, capsys):
    html = tmp_path / "play" / "run.html"
    code = main(["run", "push_constant", "--out", str(tmp_path / "out"), "--duration", "1",
                 "--no-figures", "--record", str(html)])
    assert code == 0
    assert html.is_file()
    assert any(c["type"] == "set_animation" for c in meshcat_commands(html.read_text()))
    assert str(html) in capsys.readouterr().out


def test_cli_unwritable_record_exits_2_before_simulating(tmp_path, capsys):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    code = main(["run", "push_constant", "--out", str(tmp_path / "out"), "--duration", "1",
                 "--no-figures", "--record", str(blocker / "run.html")])
    assert code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "record = " in err and "is not writable" in err
    assert not (tmp_path / "out").exists()
