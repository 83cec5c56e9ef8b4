"""A controller, an identifier and a metric added the documented way
(docs/extending.md, "Adding a controller", "Adding an identifier", "Adding a
metric"): a factory with its declaration, in a package of its own
registered by one entry-point line each, or a metric function with its
Score; then the scenario validates it when it loads, the station wires and
logs it, a run scores it, and the benchmark lists or ranks it."""

import sys
import textwrap

import pytest

from drake_contact import MakeContactDiagram, ScenarioError, load_scenario, simulate_scenario
from drake_contact.plugins import CONTROLLER_GROUP, IDENTIFIER_GROUP

TOY = '''
# [docs: toy package]
import dataclasses as dc

from pydrake.systems.framework import LeafSystem

from drake_contact.errors import ScenarioError
from drake_contact.plugins import declare, typed_options


@dc.dataclass
class DampingConfig:
    # Joint damping (N m s/rad).
    gain: float = 2.0

    def validate(self, prefix):
        if not self.gain > 0:
            raise ScenarioError(f"{prefix}.gain = {self.gain} is out of range: must be > 0")


class Damping(LeafSystem):
    """tau = -gain q_dot, whatever f_d is (a damper, not a force controller);
    also outputs its effort |tau|, a debug value and an internal one."""

    def __init__(self, config):
        super().__init__()
        self.gain = config.gain
        self.DeclareVectorInputPort("joint_velocities_estimated", 3)
        self.DeclareVectorInputPort("force_desired", 1)
        self.DeclareVectorOutputPort("joint_torque_commanded", 3, self.torque)
        self.DeclareVectorOutputPort("effort", 1, lambda c, o: o.SetAtIndex(
            0, abs(self.gain * self.get_input_port(0).Eval(c)).sum()))
        self.DeclareVectorOutputPort("debug", 1, lambda c, o: o.SetAtIndex(0, 1.0))
        self.DeclareVectorOutputPort("internal", 2, lambda c, o: o.SetZero())

    def torque(self, context, output):
        output.SetFromVector(-self.gain * self.get_input_port(0).Eval(context))


@declare(check_options=typed_options(DampingConfig, "controller.options"),
         signals={"effort": "sum of |tau| over the joints (N m)"}, unlogged=("internal",))
def damping(options):
    return Damping(DampingConfig(**options))


@declare(contender=False)
def harness(options):
    return Damping(DampingConfig())


@dc.dataclass
class ConstantConfig:
    stiffness: float = 1000.0


class Constant(LeafSystem):
    def __init__(self, stiffness):
        super().__init__()
        self.DeclareVectorInputPort("force", 1)
        self.DeclareVectorOutputPort("impedance", 3, lambda c, o: o.SetFromVector(
            [0.0, 0.0, stiffness]))


@declare(check_options=typed_options(ConstantConfig, "identifiers.options"))
def constant(options):
    return Constant(ConstantConfig(**options).stiffness)
# [docs: end]
'''


@pytest.fixture
def toy_package(tmp_path):
    """The package, installed as pip would (a .dist-info with
    entry_points.txt on the path): one line per controller or identifier."""
    site = tmp_path / "site"
    (site / "toy_extensions").mkdir(parents=True)
    (site / "toy_extensions" / "__init__.py").write_text(textwrap.dedent(TOY))
    info = site / "toy_extensions-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: toy_extensions\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(
        f"[{CONTROLLER_GROUP}]\ndamping = toy_extensions:damping\n"
        "harness = toy_extensions:harness\n"
        f"[{IDENTIFIER_GROUP}]\nconstant = toy_extensions:constant\n")
    sys.path.insert(0, str(site))
    yield site
    sys.path.remove(str(site))
    sys.modules.pop("toy_extensions", None)


def test_a_controller_is_validated_wired_logged_scored_and_ranked(toy_package):
    from drake_contact.app.benchmark import contender_names
    # Validated when the scenario loads, in one line naming the field.
    with pytest.raises(ScenarioError, match=r"controller.options.gain = -1.0 is out of range"):
        load_scenario("nn_styrofoam", ["controller.name=damping", "controller.options.gain=-1"])
    with pytest.raises(ScenarioError, match=r"controller.options.gian"):
        load_scenario("nn_styrofoam", ["controller.name=damping", "controller.options.gian=1"])
    scenario = load_scenario("nn_styrofoam", ["controller.name=damping",
                                              "controller.options.gain=3.0"], duration=0.6)
    # Wired and logged: its declared signal under its own name, the other
    # output as controller_<port>, the unlogged one not at all.
    station = MakeContactDiagram(scenario)
    assert {"effort", "controller_debug"} <= set(station.signals)
    assert "controller_internal" not in station.signals
    assert station.signals["effort"].meaning == "sum of |tau| over the joints (N m)"
    result = simulate_scenario(scenario)
    assert result.status == "completed"
    assert result.log["controller_debug"][-1] == pytest.approx(1.0)
    # Scored as any controller is: the station's detector saw no contact
    # (a damper does not push), and the peak force says why.
    assert result.metrics["contact_time_s"] is None
    assert result.metrics["peak_force_n"] < 1.0
    # Ranked by the benchmark by default; a harness only when asked for.
    names = contender_names()
    assert "damping" in names and "harness" not in names
    assert contender_names("harness") == ["harness"]


def test_an_identifier_is_validated_wired_and_listed(toy_package):
    from drake_contact.app.benchmark import identifier_entries
    with pytest.raises(ScenarioError, match=r"identifiers.options.stifness"):
        load_scenario("identify_styrofoam",
                      ["identifiers=[{name: c, kind: constant, options: {stifness: 1}}]"])
    scenario = load_scenario("identify_styrofoam", [
        "identifiers=[{name: c, kind: constant, options: {stiffness: 7000.0}}]"])
    assert "impedance_c" in MakeContactDiagram(scenario).signals
    assert identifier_entries()["constant"] == {"name": "constant", "kind": "constant"}



def test_a_metric_is_computed_scored_and_ranked(tmp_path):
    """A metric function with its Score, registered inside the test: every
    run's metrics.json has it, the benchmark puts it in runs.csv, takes its
    median and worst over the walls and shows the column it asks for."""
    import json

    import numpy as np

    from drake_contact.app import benchmark
    from drake_contact.scoring.metrics import Score, register_metric, unregister_metric

    # [docs: metric]
    score = Score("deepest_mm", "deepest_penetration_m", "deepest (mm)", ("worst",), 3,
                  scale=1e3)

    @register_metric(score)
    def deepest(log, scenario):
        return {"deepest_penetration_m": float(np.max(log["penetration_true"]))}
    # [docs: end]

    try:
        result = simulate_scenario(load_scenario("push_constant", duration=2.6))
        deep = result.metrics["deepest_penetration_m"]
        assert 0 < deep == pytest.approx(float(np.max(result.log["penetration_true"])))
        with pytest.raises(ValueError, match="the score column 'deepest_mm' is taken"):
            register_metric(Score("deepest_mm", "other"))(lambda log, scenario: {})
        run_dir = tmp_path / "run"
        run_dir.mkdir()
        (run_dir / "metrics.json").write_text(json.dumps(result.metrics | {"contact_time_s": 2.1}))
        run = benchmark.Run("toy", "hold", 0, 5000.0, 30.0)
        row = benchmark.score_run(run, run_dir)
        assert row["deepest_mm"] == pytest.approx(1e3 * deep)
        board = benchmark.aggregate([row], ["toy"], ["hold"])
        assert board[0]["deepest_mm_worst"] == pytest.approx(1e3 * deep)
        text = benchmark.markdown(board, "toy", benchmark.Suite(
            walls=((5000.0, 30.0),), tasks=("hold",), duration_s=16.0, window_s=(1.0, 6.0)))
        assert "| deepest (mm) |" in text and f"| {1e3 * deep:.3f} |" in text
    finally:
        unregister_metric(deepest)
    assert "deepest_penetration_m" not in simulate_scenario(
        load_scenario("push_constant", duration=0.6)).metrics


def test_a_measured_signal_is_one_entry_of_the_table(monkeypatch):
    """A new measured signal is a Measurement in MEASUREMENTS (here a second
    name for the DSP's ADC reading): the station fills it, exports and logs
    it under its name, a controller reads it by that name and an identifier
    by its role."""
    import numpy as np

    from drake_contact import measured
    from drake_contact.plugins import controller_inputs, identifier_inputs

    monkeypatch.setitem(measured.MEASUREMENTS, "force_adc", measured.Measurement(
        1, "the DSP's ADC reading again (N)", "dsp", "force_measured", "adc_force"))
    assert controller_inputs()["force_adc"] == (1, "the DSP's ADC reading again (N)")
    assert "adc_force" in identifier_inputs()
    scenario = load_scenario("nn_styrofoam", duration=0.6)
    assert MakeContactDiagram(scenario).signals["force_adc"].meaning == \
        "the DSP's ADC reading again (N)"
    log = simulate_scenario(scenario).log
    np.testing.assert_array_equal(log["force_adc"], log["force_measured"])
