"""Plug-in controllers: found through entry points, wired by port name,
refused in one line when they do not fit; the example package as a user
installs it (the README's test command pip-installs examples/jt_pi_controller)."""

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from drake_contact import MakeContactDiagram, ScenarioError, dump_scenario, load_scenario
from drake_contact.plant.arm import ApplySampledUpdates
from drake_contact.plugins import (
    CONTROLLER_GROUP, ContactDetector, MakeController, installed_controllers)


def drake_contact(*args, cwd, env=None):
    return subprocess.run([sys.executable, "-m", "drake_contact", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300)


def test_builtins_register_through_the_entry_point_group():
    found = installed_controllers()
    assert {"push", "hybrid", "nn"} <= set(found)
    assert all(ep.group == CONTROLLER_GROUP for ep in found.values())
    assert found["hybrid"].value == "drake_contact.control.builtin:hybrid"


def test_the_example_package_is_installed_and_found():
    found = installed_controllers()
    assert "jt_pi" in found, "pip install ./examples/jt_pi_controller (the README's test command)"
    system = MakeController("jt_pi", {"kp": 0.3})
    assert system.GetOutputPort("joint_torque_commanded").size() == 3
    with pytest.raises(ScenarioError, match=r"controller 'jt_pi' \(drake_contact_jt_pi:"
                                            r"make_controller\) raised while being built: "
                                            r"ValueError: unknown options \['gain'\]"):
        MakeController("jt_pi", {"gain": 1})


def test_the_example_runs_in_nn_styrofoams_environment_from_the_cli(tmp_path):
    out = tmp_path / "out"
    result = drake_contact("run", "nn_styrofoam", "--out", str(out), "--duration", "6",
                           "--no-figures", "--no-baseline", "--set", "controller.name=jt_pi",
                           "--set", "controller.options.kp=0.2", "--set",
                           "scoring.window_start_s=1", "--set", "scoring.window_end_s=2",
                           cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    metrics = json.loads((out / "metrics.json").read_text())
    # The station's own detector tells contact (no contact_info output):
    # the plug-in starts pushing at 3 s, after the DSP's 2 s tare.
    assert 3.0 < metrics["contact_time_s"] < 3.5
    assert metrics["contact_losses"] == 0
    assert abs(metrics["force_mean_n"] - 20.0) < 3.0  # 20 N held 1-2 s after contact
    assert "kp: 0.2" in (out / "scenario.yaml").read_text()


def _plugin(inputs, outputs=(("joint_torque_commanded", 3),)):
    """A plug-in controller's source: a LeafSystem with these vector input
    ports and these zero outputs, and its factory ``make``."""
    lines = ["class Plugin(LeafSystem):", "    def __init__(self):", "        super().__init__()"]
    lines += [f"        self.DeclareVectorInputPort({name!r}, {size})" for name, size in inputs]
    lines += [f"        self.DeclareVectorOutputPort({name!r}, {size}, lambda c, o: o.SetZero())"
              for name, size in outputs]
    return "\n".join(lines + ["def make(options):", "    return Plugin()"]) + "\n"


BROKEN = {
    "no_torque": _plugin([("force_filtered", 1)], [("torque", 3)]),
    "strange_input": _plugin([("wall_stiffness", 1)]),
    "reads_impedance": _plugin([("impedance_estimate", 3), ("force_desired", 1)]),
    "former_name": _plugin([("force", 1)]),
    "raises": """
        def make(options):
            raise RuntimeError("no license server")
        """,
    "not_a_system": """
        def make(options):
            return 42
        """,
    # Fits the station and builds; raises while running, on a soft wall
    # only: it pushes 20 N (the built-in push, from 2.1 s, after the DSP's
    # tare) and raises once the tip is 2.5 mm past the wall's rest surface
    # (a 5 kN/m wall lets it 4 mm in at rest, a 60 kN/m one 0.33 mm, and under
    # 1 mm at the impact).
    "trips": """
        from pydrake.systems.framework import DiagramBuilder
        from drake_contact.control.builtin import push
        class Tripwire(LeafSystem):
            def __init__(self, surface_x, trip_m):
                super().__init__()
                self.DeclareVectorInputPort("tip_pose_measured", 3)
                # Read as a force controller reads it (unused): the station then
                # detects and scores its contact.
                self.DeclareVectorInputPort("force_desired", 1)
                self.DeclarePeriodicDiscreteUpdateEvent(1e-3, 0.0, self.update)
                self.surface_x, self.trip_m = surface_x, trip_m
            def update(self, context, state):
                x = self.GetInputPort("tip_pose_measured").Eval(context)[0]
                if x > self.surface_x + self.trip_m:
                    # A RuntimeError, as Drake's own errors are: still a
                    # failure, not a divergence (simulation.drake_raised).
                    raise RuntimeError(f"tripped at t = {context.get_time():.3f} s")
        def make(options):
            builder = DiagramBuilder()
            pusher = builder.AddSystem(push({"force": 20.0, "start_time": 2.1}))
            wire = builder.AddSystem(Tripwire(options.get("surface_x", 0.456),
                                              options.get("trip_m", 2.5e-3)))
            builder.ExportInput(pusher.GetInputPort("plant_state"), "plant_state")
            for name in ("tip_pose_measured", "force_desired"):
                builder.ExportInput(wire.GetInputPort(name), name)
            builder.ExportOutput(pusher.GetOutputPort("joint_torque_commanded"),
                                 "joint_torque_commanded")
            return builder.Build()
        """,
    # Builds; kills its own process (a worker dying) once the simulated time
    # reaches its option die_at_s.
    "dies": """
        import os
        class Plugin(LeafSystem):
            def __init__(self, die_at_s):
                super().__init__()
                self.DeclareVectorInputPort("force_filtered", 1)
                self.DeclareVectorOutputPort("joint_torque_commanded", 3,
                                             lambda c, o: o.SetZero())
                self.DeclarePeriodicDiscreteUpdateEvent(1e-3, 0.0, self.update)
                self.die_at_s = die_at_s
            def update(self, context, state):
                if context.get_time() >= self.die_at_s:
                    os._exit(1)
        def make(options):
            return Plugin(options.get("die_at_s", 0.1))
        """,
}


IDENTIFIERS = {
    "ratio": """
        class Plugin(LeafSystem):  # K_e = (f - 5 N) / (x - x at the 5 N switch)
            def __init__(self, floor):
                super().__init__()
                self.DeclareVectorInputPort("force", 1)
                self.DeclareVectorInputPort("tip_pose", 3)
                self.DeclareVectorInputPort("contact_info", 4)
                state = self.DeclareDiscreteState(3)
                self.DeclarePeriodicDiscreteUpdateEvent(1e-3, 0.0, self.update)
                self.DeclareStateOutputPort("impedance", state)
                self.floor = floor
            def update(self, context, state):
                info = self.GetInputPort("contact_info").Eval(context)
                if info[0] < 0:
                    return
                dx = self.GetInputPort("tip_pose").Eval(context)[0] - info[1]
                f = self.GetInputPort("force").Eval(context)[0]
                state.set_value([0.0, 0.0, (f - 5.0) / max(dx, self.floor)])
        def make(options):
            return Plugin(options.get("floor", 1e-4))
        """,
    "no_impedance": """
        class Plugin(LeafSystem):
            def __init__(self):
                super().__init__()
                self.DeclareVectorInputPort("force", 1)
                self.DeclareVectorOutputPort("stiffness", 1, lambda c, o: o.SetZero())
        def make(options):
            return Plugin()
        """,
}


@pytest.fixture
def broken_plugins(tmp_path):
    """A package of broken controllers, installed as pip would (a
    .dist-info with entry_points.txt on the path), without pip."""
    site = tmp_path / "site"
    package = site / "broken_plugins"
    package.mkdir(parents=True)
    (package / "__init__.py").write_text("")
    lines = [f"[{CONTROLLER_GROUP}]"]
    for name, source in BROKEN.items():
        (package / f"{name}.py").write_text(
            "from pydrake.systems.framework import LeafSystem\n" + textwrap.dedent(source))
        lines.append(f"{name} = broken_plugins.{name}:make")
    lines.append("[drake_contact.identifiers]")
    for name, source in IDENTIFIERS.items():
        (package / f"id_{name}.py").write_text(
            "from pydrake.systems.framework import LeafSystem\n" + textwrap.dedent(source))
        lines.append(f"{name} = broken_plugins.id_{name}:make")
    info = site / "broken_plugins-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: broken_plugins\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("\n".join(lines) + "\n")
    sys.path.insert(0, str(site))
    yield site
    sys.path.remove(str(site))
    for name in [m for m in sys.modules if m.startswith("broken_plugins")]:
        del sys.modules[name]


@pytest.mark.parametrize("name, message", [
    ("no_torque", "controller 'no_torque' (broken_plugins.no_torque:make) has no output port "
                  "'joint_torque_commanded' (3: motor command before saturation (N m))"),
    ("strange_input", "input port 'wall_stiffness' is not a station signal: the station "
                      "provides tip_pose_measured, tip_velocity_measured"),
    ("former_name", "input port 'force' is the station signal 'force_filtered' (its log key) "
                    "since 2026-11-27: rename the port 'force_filtered'"),
    ("raises", "controller 'raises' (broken_plugins.raises:make) raised while being built: "
               "RuntimeError: no license server"),
    ("not_a_system", "its factory returned a int, not a Drake System"),
])
def test_a_plugin_that_does_not_fit_is_refused_naming_it(broken_plugins, name, message):
    scenario = load_scenario("nn_styrofoam", [f"controller.name={name}"])
    with pytest.raises(ScenarioError) as info:
        MakeContactDiagram(scenario)
    assert message in str(info.value)


def test_impedance_estimate_comes_from_the_named_identifier(broken_plugins):
    scenario = load_scenario("identify_styrofoam", [
        "controller.name=reads_impedance", "controller.impedance_source=rls_matched"])
    station = MakeContactDiagram(scenario)
    assert "mode" in station.signals  # the station's detector: no contact_info of its own
    with pytest.raises(ScenarioError, match="controller.impedance_source = 'ols' names no "
                                            "identifier"):
        load_scenario("identify_styrofoam", ["controller.name=reads_impedance",
                                             "controller.impedance_source=ols"])
    with pytest.raises(ScenarioError, match="controller 'reads_impedance' reads "
                                            "impedance_estimate: name its identifier in "
                                            "controller.impedance_source"):
        MakeContactDiagram(load_scenario("identify_styrofoam",
                                         ["controller.name=reads_impedance"]))


def test_the_cli_refuses_a_plugin_without_joint_torque_with_exit_2(broken_plugins, tmp_path):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(broken_plugins), os.environ.get("PYTHONPATH", "")]))
    result = drake_contact("run", "nn_styrofoam", "--out", str(tmp_path / "out"),
                           "--set", "controller.name=no_torque", cwd=tmp_path, env=env)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in result.stderr
    assert "controller 'no_torque'" in lines[0] and "'joint_torque_commanded'" in lines[0]


def test_a_plugin_identifier_runs_beside_the_builtins_and_is_scored(broken_plugins):
    from drake_contact import simulate_scenario
    scenario = load_scenario("identify_styrofoam", [
        "identifiers=[{name: ratio, kind: ratio, options: {floor: 2.0e-4}}, {name: rls}]"],
        duration=12.0)
    assert "floor: 0.0002" in dump_scenario(scenario)
    result = simulate_scenario(scenario)
    assert result.status == "completed"
    assert {"impedance_ratio", "impedance_rls"} <= set(result.log)
    # Scored against the true wall like the built-ins: the force and the
    # displacement since the switch, within a few % of K_e once settled.
    k = result.metrics["identified_impedance_ratio"]["stiffness"]
    assert abs(k / scenario.environment.stiffness - 1) < 0.1


def test_a_plugin_identifier_without_impedance_is_refused(broken_plugins):
    scenario = load_scenario("identify_styrofoam",
                             ["identifiers=[{name: bad, kind: no_impedance}]"])
    with pytest.raises(ScenarioError, match=r"identifier 'no_impedance' \(broken_plugins."
                                            r"id_no_impedance:make\) has no output port "
                                            r"'impedance'"):
        MakeContactDiagram(scenario)
    with pytest.raises(ScenarioError, match=r"identifiers\[0\].kind = 'ols' is unknown: "
                                            r"choose one of .*nn, .*ratio, .*rls"):
        load_scenario("identify_styrofoam", ["identifiers=[{name: a, kind: ols}]"])


def test_an_unknown_controller_lists_the_installed_ones():
    with pytest.raises(ScenarioError, match=r"controller.name = 'pid' is unknown: choose one of "
                                            r".*hybrid, .*nn, .*push"):
        load_scenario("nn_styrofoam", ["controller.name=pid"])


def test_a_typed_builtin_refuses_options():
    with pytest.raises(ScenarioError, match=r"controller.options: the built-in 'hybrid' is "
                                            r"configured by controller.hybrid"):
        load_scenario("hybrid_p_only_styrofoam", ["controller.options.gain=3"])


def test_options_must_be_numbers_strings_or_lists():
    with pytest.raises(ScenarioError, match=r"controller.options.gains = \{'a': 1\} must be"):
        load_scenario("nn_styrofoam", ["controller.name=jt_pi", "controller.options.gains={a: 1}"])


def test_options_survive_the_resolved_scenario():
    scenario = load_scenario("nn_styrofoam", ["controller.name=jt_pi",
                                              "controller.options.kp=0.3",
                                              "controller.options.mode=fast",
                                              "controller.options.axes=[1, 2]"])
    again = load_scenario(dump_scenario(scenario))
    assert again.controller.options == {"kp": 0.3, "mode": "fast", "axes": [1, 2]}
    assert again == scenario


def test_the_contact_detector_switches_at_5_n_and_records_the_pose():
    detector = ContactDetector()
    context = detector.CreateDefaultContext()
    detector.GetInputPort("tip_pose").FixValue(context, [0.457, 0.001, 0.002])
    context.SetTime(2.0)
    detector.GetInputPort("force").FixValue(context, [4.9])
    assert detector.GetOutputPort("mode").Eval(context)[0] == 0.0
    assert detector.GetOutputPort("contact_info").Eval(context)[0] == -1.0
    detector.GetInputPort("force").FixValue(context, [5.1])
    np.testing.assert_array_equal(detector.GetOutputPort("contact_info").Eval(context),
                                  [2.0, 0.457, 0.001, 0.002])
    ApplySampledUpdates(detector, context)
    # Later samples keep the first switch time; below 0 N contact is lost.
    context.SetTime(2.5)
    detector.GetInputPort("force").FixValue(context, [-0.1])
    assert detector.GetOutputPort("mode").Eval(context)[0] == 0.0
    assert detector.GetOutputPort("contact_info").Eval(context)[0] == 2.0


def _contact_scenarios():
    from drake_contact.resources import bundled_scenario_names
    return [name for name in bundled_scenario_names()
            if load_scenario(name).controller.name in ("hybrid", "nn")]


@pytest.mark.parametrize("name", _contact_scenarios())
def test_the_example_wires_into_every_contact_scenario(name):
    """jt_pi declares only tip_pose, tip_velocity, joint_positions, force,
    force_desired and joint_torque_commanded: the station supplies the rest
    (force reference, contact detector for the identifiers and metrics)."""
    from drake_contact import simulate_scenario
    scenario = load_scenario(name, ["controller.name=jt_pi", "simulation.settle_window=0.01",
                                    "scoring.window_start_s=0.01", "scoring.window_end_s=0.02",
                                    "scoring.rmse_window_s=0.01"], duration=0.05)
    station = MakeContactDiagram(scenario)
    assert station.signals["mode"].meaning.startswith("the station's contact detector")
    assert "contact_info" in station.signals and "force_desired" in station.signals
    result = simulate_scenario(scenario)
    assert result.status == "completed"
    assert np.all(result.log["contact_info"][:, 0] == -1.0)  # no contact in 50 ms
