"""Online identification in a run: several identifiers side by side, from
the first contact switch (the thesis's Figs 6.1-6.9; scored by
:mod:`drake_contact.scoring.metrics`).

Each identifier is named; its estimate is logged as ``impedance_<name>``
(N x 3: M_e, B_e, K_e) and scored in ``metrics.json`` as
``identified_impedance_<name>``, ``identification_time_<name>_s`` (time after
the switch from which the K_e estimate stays within 5 % of the truth) and
``identification_error_<name>`` (relative errors), and the same time for
10 % as ``identification_time_10pct_<name>_s`` (the neural identifier's bar). ``stiffness_ratio`` is the
thesis's "measured" stiffness f / xe from the filtered force and the
estimated displacement since the switch.

Signals an identifier reads (``signals``):

- ``thesis`` (line 675 of the thesis: "measured force f, robot manipulator
  position x, velocity and acceleration are used; a 35Hz Butterworth
  low-pass filter is used only for the noisy acceleration signal"): the
  120 Hz filtered force, the DSP's measured force (line 673; Appendix E's
  f / x, ``Kcm = uff/x1e``, divides the same filtered force ``uff``, and the
  thesis sets its RLS beside that f / x); xe from the estimated tip
  position; xe' the unfiltered backward difference; xe'' through the 35 Hz
  filter.
- ``filtered`` (ours): as ``thesis``, with xe' through the 35 Hz filter too.
- ``raw``: the unfiltered force and the unfiltered differences (Fig 6.3).
- ``matched`` (ours, not the thesis's): the same signals, each passed through
  the filters the others went through, so that all four see one and the
  same linear filter and f = M xe'' + B xe' + K xe (+ f_0) holds between
  them exactly. The force chain (sensor's 120 Hz analog filter, 480 Hz hold,
  500 Hz output stage, DSP's 120 Hz filter) lags the force by about 6 ms and
  the 35 Hz estimator lags xe' and xe'' by about 7 ms, but xe has no lag; in
  the ~100 ms switch transient, the only excitation there is, that mismatch
  biases K_e by 5-12 % on styrofoam. ``matched`` passes the force through
  the estimator's 35 Hz filter, xe through a nominal model of the force
  chain and the 35 Hz filter, and xe', xe'' through the nominal force chain
  (:func:`nominal_force_chain`): Drake LinearSystems in front of the
  identifier.
- ``raw_matched`` (ours): the DSP's unfiltered force, and xe, xe',
  xe'' (the unfiltered differences) each through the nominal model of the
  sensor's chain up to the DSP (:func:`nominal_force_chain` without its
  120 Hz stage). The model is matched as above, but the force's noise is
  left as it is read: nearly white at 1 kHz (the gauge noise held at
  480 Hz), where the 120 Hz and 35 Hz filters make it coloured over several
  samples. The controller feeds that noise back into the motion within a
  few samples, so coloured noise is correlated with the regressors and
  biases least squares (the equation-error bias of closed-loop data: L.
  Ljung, System Identification, 2nd ed., 1999, sections 7.3 and 13.4;
  T. Soderstrom and P. Stoica, System Identification, 1989, chapter 10);
  white noise is not. Measured: the bias of ``matched`` on identify_any
  (median -3.9 % at the end) is the force noise (the same fit on the
  noise-free force: -0.6 %); see docs/reproduction.md.
"""

import dataclasses as dc
import zlib
from types import SimpleNamespace

import numpy as np
from scipy import signal
from pydrake.systems.framework import DiagramBuilder

from drake_contact.arm_axis import LinearSystemBank
from drake_contact.blocks import AddSubdiagram, EnvironmentCopies, system_ports
from drake_contact.errors import ScenarioError
from drake_contact.measured import MEASUREMENTS
from drake_contact.plant.arm import CONTROL_PERIOD
from drake_contact.structure import check_ensemble_structure, identifiers_structure
from drake_contact.sensing.filters import butterworth_digital, digital_filter_system
from drake_contact.identification import nn_identifier, rls_identifier
from drake_contact.identification.nn_identifier import NnIdentifier, NnIdentifierConfig
from drake_contact.identification.rls_identifier import RlsConfig, RlsIdentifier
from drake_contact.options import config_from_options
from drake_contact.plugins import (
    MakeIdentifier, check_configuration, configured_options, declare, identifier_declaration,
    installed_identifiers)

SIGNALS = ("thesis", "filtered", "raw", "matched", "raw_matched")
CHAIN_MODELS = ("bilinear", "zoh")


@dc.dataclass
class IdentifierConfig:
    """One online identifier."""

    # Its name: logs impedance_<name>, metrics *_<name>.
    name: str = "rls"
    # An installed identifier (drake_contact.plugins.installed_identifiers():
    # the built-ins rls and nn, configured by the sections below, or a plug-in).
    kind: str = "rls"
    # Signals it reads: thesis (line 675: 120 Hz force, unfiltered velocity,
    # 35 Hz acceleration), filtered (ours: 120 Hz force, 35 Hz velocity
    # and acceleration), raw (unfiltered force and differences, Fig 6.3) or
    # matched (all four through one common filter; see the module doc) or
    # raw_matched (the unfiltered force, the kinematics through the sensor's
    # nominal chain; ours, see the module doc).
    signals: str = "filtered"
    # The nominal force chain of the matched and raw_matched signals:
    # bilinear (its analog stages by Tustin's rule, for a force that varies
    # between samples) or zoh (held over each 1 ms sample, as the simulated
    # sensor holds the wall's force: exact in simulation; ours).
    # See nominal_force_chain.
    chain_model: str = "bilinear"
    # Thesis figures it belongs to, e.g. ["6.1", "6.2"]: the first is the
    # six-panel figure of the first 4 s (identifiers naming the same one share
    # its axes), the second the whole run (RLS) or the network's output error
    # (NN, Fig 6.8). Empty: drawn in identification_<name>.png.
    figures: list[str] = dc.field(default_factory=list)
    rls: RlsConfig = dc.field(default_factory=RlsConfig)
    nn: NnIdentifierConfig = dc.field(default_factory=NnIdentifierConfig)
    # Options of a plug-in identifier (names to numbers, lists or strings),
    # handed to its factory; the built-ins take their section above.
    options: dict[str, float] = dc.field(default_factory=dict)
    # What seeds its random initial state (the network's weights) with the
    # run's seed; empty: its name. Identifiers with the same key start alike
    # (the thesis's two learning rates of Fig 6.6), wherever they stand in
    # the list and whichever environment of an ensemble they serve.
    seed_key: str = ""

    def seed(self, run_seed: int) -> int:
        """Its initial state's seed in a run seeded ``run_seed``: a function
        of the run's seed and :attr:`seed_key` (or the name) alone."""
        key = zlib.crc32((self.seed_key or self.name).encode())
        return int(np.random.SeedSequence([run_seed, key]).generate_state(1)[0])

    def factory_options(self, run_seed: int) -> dict:
        """The options mapping the identifier's factory gets: the built-ins'
        typed section (the network also its weights' ``seed``, from
        :meth:`seed`), else ``options``."""
        declared = identifier_declaration(self.kind)
        options = configured_options(self, declared)
        return options | {"seed": self.seed(run_seed)} if declared.seeded else options

    def validate(self, prefix):
        if not self.name.isidentifier():
            raise ScenarioError(f"{prefix}.name = '{self.name}' is not a valid name: "
                                "use letters, digits and underscores")
        installed = installed_identifiers()
        if self.kind not in installed:
            raise ScenarioError(f"{prefix}.kind = '{self.kind}' is unknown: choose one of "
                                f"{', '.join(sorted(installed))}")
        check_configuration(self, identifier_declaration(self.kind, f"{prefix}.kind"), prefix,
                            self.kind)
        if self.signals not in SIGNALS:
            raise ScenarioError(f"{prefix}.signals = '{self.signals}' is unknown: choose one of "
                                f"{', '.join(SIGNALS)}")
        if self.chain_model not in CHAIN_MODELS:
            raise ScenarioError(f"{prefix}.chain_model = '{self.chain_model}' is unknown: choose "
                                f"one of {', '.join(CHAIN_MODELS)}")
        if self.seed_key and not self.seed_key.isidentifier():
            raise ScenarioError(f"{prefix}.seed_key = '{self.seed_key}' is not a valid key: "
                                "use letters, digits and underscores, or leave it empty")
        if len(self.figures) > 2 or not all(
                all(part.isdigit() for part in str(f).split(".")) for f in self.figures):
            raise ScenarioError(f"{prefix}.figures = {self.figures} is out of range: at most 2 "
                                "figure numbers like '6.1'")


def validate_identifiers(identifiers, prefix="identifiers"):
    names = set()
    for i, config in enumerate(identifiers):
        config.validate(f"{prefix}[{i}]")
        if config.name in names:
            raise ScenarioError(f"{prefix}[{i}].name = '{config.name}' is used twice")
        names.add(config.name)


def nominal_force_chain(sensor, dsp, period=CONTROL_PERIOD, discretization="bilinear"):
    """(b, a) at 1 kHz of the force chain's nominal linear model, from true
    force to ``force_filtered``: the sensor's analog Butterworth and its 2nd-
    order output stage, the 480 Hz hold as one sample of delay (its mean
    delay, 1.04 ms), and the DSP's 2nd-order Butterworth (none with
    ``dsp=None``: to ``force_measured``). The identifiers' ``matched`` and
    ``raw_matched`` signals use it.

    ``discretization`` of the analog stages: ``bilinear`` (Tustin: for a
    force that varies continuously between samples, as on hardware) or
    ``zoh`` (exact for a force held over each sample, as the simulated
    sensor holds the wall's force over each 1 ms frame of its fine ticks:
    a staircase, whose mean delay is half a sample more). Against the simulated chain,
    noise-free, at 1.7-20 Hz: ``bilinear`` lags it by 0.54-0.62 ms, ``zoh``
    by 0.04-0.12 ms (tests/test_sensor_chain.py). A force that lags its
    model by tau reads, in f = M_e a + B_e v + K_e x, as B_e - tau K_e: 0.6
    ms is 90 N s/m at 150 kN/m."""
    num, den = signal.butter(sensor.analog_order, 2 * np.pi * sensor.analog_cutoff_hz,
                             analog=True)
    num_o, den_o = signal.butter(2, 2 * np.pi * sensor.output_bandwidth_hz, analog=True)
    num, den = np.polymul(num, num_o), np.polymul(den, den_o)
    if discretization == "zoh":
        b, a, _ = signal.cont2discrete((num, den), period, method="zoh")
        b, a = np.ravel(b), np.ravel(a)
    else:
        b, a = signal.bilinear(num, den, 1.0 / period)
    hold_delay = max(1, int(round(0.5 / sensor.adc_rate_hz / period)))
    if dsp is None:
        return np.concatenate([np.zeros(hold_delay), b]), a
    b_dsp, a_dsp = butterworth_digital(dsp.force_filter_cutoff_hz, 1.0 / period)
    # np.convolve, not np.polymul: the latter drops the zoh numerator's
    # leading zero, a sample of delay.
    return (np.concatenate([np.zeros(hold_delay), np.convolve(b, b_dsp)]),
            np.convolve(a, a_dsp))


def _add_matched_signals(builder, scenarios, inputs, chain_model="bilinear"):
    """The ``matched`` versions of force, tip pose, velocity and acceleration:
    every one through the same overall filter (force chain x 35 Hz), each
    environment's from its own scenario (``scenarios``: one per environment).
    ``inputs`` maps a measured signal's name to the list of inner input
    ports its exported input feeds; returns {signal name: filtered port}."""
    filters = {"force": ("force", [], 1), "tip_pose": ("pose", [], 3),
               "tip_velocity": ("velocity", [], 3), "tip_acceleration": ("acceleration", [], 3)}
    for scenario in scenarios:
        b_chain, a_chain = nominal_force_chain(scenario.force_sensor, scenario.dsp,
                                               discretization=chain_model)
        b_35, a_35 = butterworth_digital(scenario.estimator.cutoff_hz, 1.0 / CONTROL_PERIOD)
        filters["force"][1].append((b_35, a_35))
        filters["tip_pose"][1].append((np.polymul(b_chain, b_35), np.polymul(a_chain, a_35)))
        filters["tip_velocity"][1].append((b_chain, a_chain))
        filters["tip_acceleration"][1].append((b_chain, a_chain))
    return _add_filters(builder, filters, inputs, chain_model)


def _add_raw_matched_signals(builder, scenarios, inputs, chain_model="bilinear"):
    """The ``raw_matched`` signals: the unfiltered force as read, and the tip
    pose and its unfiltered differences through the sensor's nominal chain
    up to the DSP. Returns {identifier input name: port} like
    :func:`_add_matched_signals`."""
    chains = [nominal_force_chain(s.force_sensor, None, discretization=chain_model)
              for s in scenarios]
    filters = {
        "tip_pose": ("raw_pose", chains, 3),
        "tip_velocity_raw": ("raw_velocity", chains, 3),
        "tip_acceleration_raw": ("raw_acceleration", chains, 3),
    }
    out = _add_filters(builder, filters, inputs, chain_model)
    return {"tip_pose": out["tip_pose"], "tip_velocity": out["tip_velocity_raw"],
            "tip_acceleration": out["tip_acceleration_raw"]}


def _add_filters(builder, filters, inputs, chain_model="bilinear"):
    """Adds one digital filter system per entry {source: (name, [(b, a) per
    environment], channels)}, fed by the measured signal ``source``; returns
    {source: its output port}. The systems are named matched_<name> (and
    _zoh with that chain model); for several environments each is a
    LinearSystemBank of their filters (env-major ports)."""
    out = {}
    suffix = "" if chain_model == "bilinear" else f"_{chain_model}"
    for source, (name, coefficients, channels) in filters.items():
        systems = [digital_filter_system(b, a, CONTROL_PERIOD, channels)
                   for b, a in coefficients]
        system = builder.AddNamedSystem(f"matched_{name}{suffix}", systems[0] if len(systems) == 1
                                        else LinearSystemBank(systems))
        inputs[source].append(system.get_input_port())
        out[source] = system.get_output_port()
    # The position filter starts at rest at 0 and settles within ~50 ms,
    # long before any contact. xe is still referenced to the unfiltered x at
    # the switch: the ~10 um difference is absorbed by the force offset f_0.
    return out


#: Which measured signal feeds each identifier input, per ``signals``.
_SOURCES = {
    "thesis": {"force": "force", "tip_pose": "tip_pose", "tip_velocity": "tip_velocity_raw",
               "tip_acceleration": "tip_acceleration"},
    "filtered": {"force": "force", "tip_pose": "tip_pose", "tip_velocity": "tip_velocity",
                 "tip_acceleration": "tip_acceleration"},
    "raw": {"force": "force_raw", "tip_pose": "tip_pose", "tip_velocity": "tip_velocity_raw",
            "tip_acceleration": "tip_acceleration_raw"},
}
# What the filtered matched signals do not replace (matched: none of the four;
# raw_matched: the force, read unfiltered).
_SOURCES["matched"] = _SOURCES["filtered"]
_SOURCES["raw_matched"] = _SOURCES["raw"]


def _rls_structure(options: dict) -> dict:
    """What an RLS section ``options`` (checked when the scenario loaded)
    switches on, as ``rls.<field>``."""
    config = SimpleNamespace(**options)
    return {f"rls.{field}": value for field, value in rls_identifier.structure(config).items()}


def _nn_structure(options: dict) -> dict:
    """What a network section ``options`` switches on, as ``nn.<field>``."""
    config = SimpleNamespace(**options)
    return {f"nn.{field}": value for field, value in nn_identifier.structure(config).items()}


@declare(sections=("rls",), ensemble=True, structure=_rls_structure)
def rls(options):
    """The built-in RLS identifier (registered as ``rls``); options: the
    fields of :class:`RlsConfig`, or a list of N such mappings (one system
    serving N environments)."""
    configs = [config_from_options(RlsConfig, o, "identifiers.rls")
               for o in (options if isinstance(options, list) else [options])]
    return RlsIdentifier(configs if isinstance(options, list) else configs[0])


@declare(sections=("nn",), seeded=True, ensemble=True, structure=_nn_structure)
def nn(options):
    """The built-in neural identifier (registered as ``nn``); options: the
    fields of :class:`NnIdentifierConfig` and ``seed`` (its initial weights),
    or a list of N such mappings (one system serving N environments, each's
    weights from its own seed)."""
    configs, seeds = [], []
    for o in (options if isinstance(options, list) else [options]):
        o = dict(o)
        seeds.append(int(o.pop("seed", 0)))
        configs.append(config_from_options(NnIdentifierConfig, o, "identifiers.nn"))
    if isinstance(options, list):
        return NnIdentifier(configs, seeds)
    return NnIdentifier(configs[0], seeds[0])


def _make_identifier(scenarios, index):
    """The identifier system of entry ``index`` for the environments'
    ``scenarios``: one system, or with several environments one serving all
    when its plug-in declares ``ensemble``, else
    :class:`~drake_contact.blocks.EnvironmentCopies` of one per environment."""
    configs = [s.identifiers[index] for s in scenarios]
    kind, prefix = configs[0].kind, f"identifiers[{index}]"
    options = [c.factory_options(s.simulation.seed) for c, s in zip(configs, scenarios)]
    if len(scenarios) == 1:
        return MakeIdentifier(kind, options[0], prefix=prefix)
    if identifier_declaration(kind, f"{prefix}.kind").ensemble:
        return MakeIdentifier(kind, options, prefix=prefix, count=len(scenarios))
    copies = [MakeIdentifier(kind, o, prefix=prefix) for o in options]
    return EnvironmentCopies(f"identifier_{configs[0].name}", len(copies), lambda builder, i:
                             system_ports(builder.AddSystem(copies[i])))


def AddIdentifiers(builder: DiagramBuilder, scenario, *, name="identifiers"):
    """Adds every one of ``scenario.identifiers`` side by side, as the
    sub-diagram ``name``; returns it.

    Inputs: every measured signal (:data:`~drake_contact.measured.MEASUREMENTS`) by
    its role (``force``, ``force_raw``, ``tip_pose``, ...) and
    ``contact_info`` (4, the hybrid controller's switch record), and
    ``force_fault`` (1, the safety supervisor's flag; unconnected without
    one) if an identifier reads it. Outputs, per
    identifier ``<id>``: ``impedance_<id>`` (3: [M_e, B_e, K_e], kg, N s/m,
    N/m) and, for the neural network, ``force_estimate_<id>`` (N).

    ``scenario`` may be a list of N scenarios, one per environment of an
    ensemble, with the same identifiers (names, kinds, signals, chain
    models; their numbers and seeds may differ): then every port is N times
    its size, env-major (environment i's k values at [k i, k i + k)), each
    identifier one system serving all N when its plug-in declares
    ``ensemble`` (else N copies behind a Demultiplexer and a Multiplexer per
    port), each matched filter a LinearSystemBank of the N environments'."""
    scenarios = list(scenario) if isinstance(scenario, (list, tuple)) else [scenario]
    if not scenarios:
        raise ScenarioError("identifiers: no scenarios (one per environment, at least one)")
    check_ensemble_structure(scenarios, identifiers_structure)
    first = scenarios[0]

    def build(builder):
        inputs = {m.role: [] for m in MEASUREMENTS.values()} | {"contact_info": [],
                                                                "force_fault": []}
        outputs = {}
        filtered = {}   # (signals, chain) -> {input name: filtered port}, built once each
        adders = {"matched": _add_matched_signals, "raw_matched": _add_raw_matched_signals}
        for index, config in enumerate(first.identifiers):
            system = builder.AddNamedSystem(f"identifier_{config.name}",
                                            _make_identifier(scenarios, index))
            key = (config.signals, config.chain_model)
            if config.signals in adders and key not in filtered:
                filtered[key] = adders[config.signals](builder, scenarios, inputs,
                                                       config.chain_model)
            own = filtered.get(key, {})
            sources = _SOURCES[config.signals]
            for i in range(system.num_input_ports()):
                port = system.get_input_port(i)
                port_name = port.get_name()
                field = sources.get(port_name, port_name)
                if port_name in own:
                    builder.Connect(own[port_name], port)
                else:  # contact_info, force_fault, or a measured signal
                    inputs[field].append(port)
            outputs[f"impedance_{config.name}"] = system.GetOutputPort("impedance")
            if system.HasOutputPort("force_estimate"):
                outputs[f"force_estimate_{config.name}"] = system.GetOutputPort("force_estimate")
        return {port: ports for port, ports in inputs.items() if ports} | outputs
    return AddSubdiagram(builder, name, build)
