"""Online identification in a run: several identifiers side by side, their
scores against the true impedance, and the thesis's figures (6.1-6.9).

Each identifier is named; its estimate is logged as ``impedance_<name>``
(N x 3: M_e, B_e, K_e) and scored in ``metrics.json`` as
``identified_impedance_<name>``, ``identification_time_<name>_s`` (time after
the switch from which the K_e estimate stays within 5 % of the truth) and
``identification_error_<name>`` (relative errors). ``stiffness_ratio`` is the
thesis's "measured" stiffness f / xe from the filtered force and the
estimated displacement since the switch.
"""

import dataclasses as dc

import numpy as np
from pydrake.systems.framework import DiagramBuilder

from drake_contact.errors import ScenarioError
from drake_contact.nn_identifier import NnIdentifier, NnIdentifierConfig
from drake_contact.rls_identifier import RlsConfig, RlsIdentifier

KINDS = ("rls", "nn")
SIGNALS = ("filtered", "raw")
SETTLE_TOLERANCE = 0.05


@dc.dataclass
class IdentifierConfig:
    """One online identifier."""

    # Its name: logs impedance_<name>, metrics *_<name>.
    name: str = "rls"
    # rls or nn.
    kind: str = "rls"
    # Signals it reads: filtered (the thesis: 120 Hz force, 35 Hz velocity
    # and acceleration) or raw (unfiltered force and differences, Fig 6.3).
    signals: str = "filtered"
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


def validate_identifiers(identifiers, prefix="identifiers"):
    names = set()
    for i, config in enumerate(identifiers):
        config.validate(f"{prefix}[{i}]")
        if config.name in names:
            raise ScenarioError(f"{prefix}[{i}].name = '{config.name}' is used twice")
        names.add(config.name)


def AddIdentifiers(builder: DiagramBuilder, identifiers, measured, contact_info, seed):
    """Adds each identifier; returns {name: {"impedance": port, ...}}.

    ``measured`` holds the estimator's and DSP's ports: force_filtered,
    force_measured, tip_pose, tip_velocity, tip_acceleration and their raw
    versions tip_velocity_raw, tip_acceleration_raw."""
    ports = {}
    for index, config in enumerate(identifiers):
        if config.kind == "rls":
            system = RlsIdentifier(config.rls)
        else:
            system = NnIdentifier(config.nn, seed=seed * 1000 + index)
        system = builder.AddNamedSystem(f"identifier_{config.name}", system)
        raw = config.signals == "raw"
        builder.Connect(measured["force_measured" if raw else "force_filtered"],
                        system.GetInputPort("force"))
        builder.Connect(measured["tip_pose"], system.GetInputPort("tip_pose"))
        builder.Connect(measured["tip_velocity_raw" if raw else "tip_velocity"],
                        system.GetInputPort("tip_velocity"))
        builder.Connect(measured["tip_acceleration_raw" if raw else "tip_acceleration"],
                        system.GetInputPort("tip_acceleration"))
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
        within = np.abs(est[:, 2] / log["true_impedance"][:, 2] - 1) < SETTLE_TOLERANCE
        outside = np.flatnonzero(after & ~within)
        if not within[-1]:
            settle = None
        elif len(outside) == 0:
            settle = 0.0
        else:
            settle = float(t[outside[-1] + 1] - t_contact)
        out[f"identification_time_{config.name}_s"] = settle
    ratio = log.get("stiffness_ratio")
    if ratio is not None:
        late = (t >= t[-1] - 1.0) & np.isfinite(ratio)
        if late.any():
            out["stiffness_ratio_final_n_per_m"] = float(np.mean(ratio[late]))
    return out
