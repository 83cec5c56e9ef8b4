"""Online identification in a run: several identifiers side by side, their
scores against the true impedance, and the thesis's figures (6.1-6.9).

Each identifier is named; its estimate is logged as ``impedance_<name>``
(N x 3: M_e, B_e, K_e) and scored in ``metrics.json`` as
``identified_impedance_<name>``, ``identification_time_<name>_s`` (time after
the switch from which the K_e estimate stays within 5 % of the truth) and
``identification_error_<name>`` (relative errors), and the same time for
10 % as ``identification_time_10pct_<name>_s`` (the neural identifier's bar). ``stiffness_ratio`` is the
thesis's "measured" stiffness f / xe from the filtered force and the
estimated displacement since the switch.

Signals an identifier reads (``signals``):

- ``filtered`` (the thesis): the 120 Hz filtered force; xe from the
  estimated tip position; xe', xe'' from the estimator (35 Hz filter).
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
"""

import dataclasses as dc

import numpy as np
from scipy import signal
from pydrake.systems.framework import DiagramBuilder

from drake_contact.arm import CONTROL_PERIOD
from drake_contact.errors import ScenarioError
from drake_contact.filters import butterworth_digital, digital_filter_system
from drake_contact.nn_identifier import NnIdentifier, NnIdentifierConfig
from drake_contact.rls_identifier import RlsConfig, RlsIdentifier

KINDS = ("rls", "nn")
SIGNALS = ("filtered", "raw", "matched")
SETTLE_TOLERANCE_NN = 0.10  # the neural identifier's bar (issue 5)
SETTLE_TOLERANCE = 0.05


@dc.dataclass
class IdentifierConfig:
    """One online identifier."""

    # Its name: logs impedance_<name>, metrics *_<name>.
    name: str = "rls"
    # rls or nn.
    kind: str = "rls"
    # Signals it reads: filtered (the thesis: 120 Hz force, 35 Hz velocity
    # and acceleration), raw (unfiltered force and differences, Fig 6.3) or
    # matched (all four through one common filter; see the module doc).
    signals: str = "filtered"
    # Thesis figures it belongs to, e.g. ["6.1", "6.2"]: the first is the
    # six-panel figure of the first 4 s (identifiers naming the same one share
    # its axes), the second the whole run (RLS) or the network's output error
    # (NN, Fig 6.8). Empty: drawn in identification_<name>.png.
    figures: list[str] = dc.field(default_factory=list)
    rls: RlsConfig = dc.field(default_factory=RlsConfig)
    nn: NnIdentifierConfig = dc.field(default_factory=NnIdentifierConfig)

    def validate(self, prefix):
        if not self.name.isidentifier():
            raise ScenarioError(f"{prefix}.name = '{self.name}' is not a valid name: "
                                "use letters, digits and underscores")
        if self.kind not in KINDS:
            raise ScenarioError(f"{prefix}.kind = '{self.kind}' is unknown: choose one of "
                                f"{', '.join(KINDS)}")
        if self.signals not in SIGNALS:
            raise ScenarioError(f"{prefix}.signals = '{self.signals}' is unknown: choose one of "
                                f"{', '.join(SIGNALS)}")
        getattr(self, self.kind).validate(f"{prefix}.{self.kind}")
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


def nominal_force_chain(sensor, dsp, period=CONTROL_PERIOD):
    """(b, a) at 1 kHz of the force chain's nominal linear model, from true
    force to ``force_filtered``: the sensor's analog Butterworth and its 2nd-
    order output stage (bilinear), the 480 Hz hold as one sample of delay
    (its mean delay, 1.04 ms), and the DSP's 2nd-order Butterworth. The
    identifiers' ``matched`` signals use it; the noise-free step response of
    the full chain is within a fraction of a sample of it."""
    num, den = signal.butter(sensor.analog_order, 2 * np.pi * sensor.analog_cutoff_hz,
                             analog=True)
    num_o, den_o = signal.butter(2, 2 * np.pi * sensor.output_bandwidth_hz, analog=True)
    b, a = signal.bilinear(np.polymul(num, num_o), np.polymul(den, den_o), 1.0 / period)
    hold_delay = max(1, int(round(0.5 / sensor.adc_rate_hz / period)))
    b_dsp, a_dsp = butterworth_digital(dsp.force_filter_cutoff_hz, 1.0 / period)
    return (np.concatenate([np.zeros(hold_delay), np.polymul(b, b_dsp)]),
            np.polymul(a, a_dsp))


def _add_matched_signals(builder, scenario, measured):
    """The ``matched`` versions of force, tip pose, velocity and acceleration:
    every one through the same overall filter (force chain x 35 Hz)."""
    b_chain, a_chain = nominal_force_chain(scenario.force_sensor, scenario.dsp)
    b_35, a_35 = butterworth_digital(scenario.estimator.cutoff_hz, 1.0 / CONTROL_PERIOD)
    filters = {
        "force_filtered": ("force", b_35, a_35, 1),
        "tip_pose": ("pose", np.polymul(b_chain, b_35), np.polymul(a_chain, a_35), 3),
        "tip_velocity": ("velocity", b_chain, a_chain, 3),
        "tip_acceleration": ("acceleration", b_chain, a_chain, 3),
    }
    out = {}
    for source, (name, b, a, channels) in filters.items():
        system = builder.AddNamedSystem(f"matched_{name}",
                                        digital_filter_system(b, a, CONTROL_PERIOD, channels))
        builder.Connect(measured[source], system.get_input_port())
        out[source] = system.get_output_port()
    # The position filter starts at rest at 0 and settles within ~50 ms,
    # long before any contact. xe is still referenced to the unfiltered x at
    # the switch: the ~10 um difference is absorbed by the force offset f_0.
    return out


def AddIdentifiers(builder: DiagramBuilder, scenario, measured, contact_info):
    """Adds each of ``scenario.identifiers``; returns {name: {"impedance": port, ...}}.

    ``measured`` holds the estimator's and DSP's ports: force_filtered,
    force_measured, tip_pose, tip_velocity, tip_acceleration and their raw
    versions tip_velocity_raw, tip_acceleration_raw."""
    identifiers, seed = scenario.identifiers, scenario.simulation.seed
    matched = None
    ports = {}
    for index, config in enumerate(identifiers):
        if config.kind == "rls":
            system = RlsIdentifier(config.rls)
        else:
            system = NnIdentifier(config.nn, seed=seed * 1000 + index)
        system = builder.AddNamedSystem(f"identifier_{config.name}", system)
        if config.signals == "matched":
            matched = matched or _add_matched_signals(builder, scenario, measured)
            source = matched
        elif config.signals == "raw":
            source = dict(measured, force_filtered=measured["force_measured"],
                          tip_velocity=measured["tip_velocity_raw"],
                          tip_acceleration=measured["tip_acceleration_raw"])
        else:
            source = measured
        builder.Connect(source["force_filtered"], system.GetInputPort("force"))
        for name in ("tip_pose", "tip_velocity", "tip_acceleration"):
            builder.Connect(source[name], system.GetInputPort(name))
        builder.Connect(contact_info, system.GetInputPort("contact_info"))
        ports[config.name] = {"impedance": system.GetOutputPort("impedance")}
        if config.kind == "nn":
            ports[config.name]["force_estimate"] = system.GetOutputPort("force_estimate")
    return ports


def add_stiffness_ratio(log: dict) -> None:
    """Adds ``stiffness_ratio`` (f / xe, N/m; NaN before contact or where xe
    is under 20 um) and ``displacement_measured`` (xe, m) to a log."""
    if "contact_info" not in log:
        return
    info = log["contact_info"]
    in_contact = info[:, 0] >= 0
    xe = np.where(in_contact, log["tip_pose_measured"][:, 0] - info[:, 1], np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(np.abs(xe) > 2e-5, log["force_filtered"] / xe, np.nan)
    log["displacement_measured"] = xe
    log["stiffness_ratio"] = ratio


def settling_time(t, ratio, after, tolerance):
    """Time from the first ``after`` sample from which |ratio - 1| stays below
    ``tolerance`` (s); None if the last sample is outside."""
    within = np.abs(ratio - 1) < tolerance
    if not within[-1]:
        return None
    outside = np.flatnonzero(after & ~within)
    start = t[np.argmax(after)]
    return 0.0 if len(outside) == 0 else float(t[outside[-1] + 1] - start)


def identification_metrics(log: dict, identifiers) -> dict:
    """Final estimates, settling times and relative errors against truth."""
    if not identifiers or "contact_info" not in log or not np.any(log["contact_info"][:, 0] >= 0):
        return {}
    t = log["t"]
    t_contact = float(log["contact_info"][-1, 0])
    truth = log["true_impedance"][-1]
    out = {}
    for config in identifiers:
        est = log[f"impedance_{config.name}"]
        final = est[-1]
        out[f"identified_impedance_{config.name}"] = {
            "mass": float(final[0]), "damping": float(final[1]), "stiffness": float(final[2])}
        with np.errstate(divide="ignore", invalid="ignore"):
            rel = (final - truth) / np.where(truth != 0, truth, np.nan)
        out[f"identification_error_{config.name}"] = {
            "mass": None if not np.isfinite(rel[0]) else float(rel[0]),
            "damping": None if not np.isfinite(rel[1]) else float(rel[1]),
            "stiffness": float(rel[2])}
        after = t >= t_contact
        for tolerance, key in ((SETTLE_TOLERANCE, f"identification_time_{config.name}_s"),
                               (SETTLE_TOLERANCE_NN, f"identification_time_10pct_{config.name}_s")):
            out[key] = settling_time(t, est[:, 2] / log["true_impedance"][:, 2], after, tolerance)
    ratio = log.get("stiffness_ratio")
    if ratio is not None:
        late = (t >= t[-1] - 1.0) & np.isfinite(ratio)
        if late.any():
            out["stiffness_ratio_final_n_per_m"] = float(np.mean(ratio[late]))
    return out
