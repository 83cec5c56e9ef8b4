"""What an ensemble's environments must share: one structure key.

:func:`ensemble_structure` maps a scenario to a hashable key, a tuple of
``(field, value)`` pairs in a fixed order, of everything that decides the
station's systems and ports: the plant step, the controller and the options
its plug-in switches on, the identifiers and theirs, the safety supervisor,
the signal of each fault, the friction model, the force sensor's sampling, the
DSP's probe channel and the force reference's probe. Two scenarios with one
key build the same station up to numbers (walls, gains, seeds, noise
levels, fault times and sizes), so they can share an ensemble
(:func:`drake_contact.diagram.MakeEnsembleDiagram`), and a campaign packs by
the key (``drake_contact.app.campaign.ensemble_packs``).

:func:`check_ensemble_structure` is the one check: it raises a one-line
:class:`~drake_contact.errors.ScenarioError` naming the first field (in the
key's order) in which an environment differs from environment 0, before
anything is built.

A plug-in that serves an ensemble in one system declares what its options
switch on with ``Declaration.structure`` (a function of one environment's
options mapping returning ``{field: value}``); the key carries it as
``controller.<field>`` or ``identifiers[k].<field>``.
"""

from drake_contact.errors import ScenarioError
from drake_contact.plugins import controller_declaration, identifier_declaration


def _hashable(value):
    if isinstance(value, (list, tuple)):
        return tuple(_hashable(v) for v in value)
    if isinstance(value, dict):
        return tuple(sorted((k, _hashable(v)) for k, v in value.items()))
    return value


def _declared(declaration, options, prefix) -> list:
    if declaration.structure is None:
        return []
    return [(f"{prefix}.{field}", _hashable(value))
            for field, value in declaration.structure(options).items()]


def ensemble_structure(scenario) -> tuple:
    """The structure key of ``scenario``: ``((field, value), ...)``,
    hashable, equal for two scenarios exactly when they can share an
    ensemble. Fields are named as in the scenario (``arm.time_step``,
    ``safety.enabled``, ``controller.hybrid.law``); ``faults`` is the signal
    each fault corrupts, in order (so their number too: the station logs
    ``fault_active`` with one column per fault), and ``identifiers`` their
    (name, kind, signals, chain_model)."""
    from drake_contact.sensing.force_sensor import _STRUCTURE as SENSOR_STRUCTURE

    controller = scenario.controller
    key = [("arm.time_step", scenario.arm.time_step),
           ("controller.name", controller.name)]
    key += _declared(controller_declaration(controller.name), controller.factory_options(),
                     "controller")
    key += identifiers_structure(scenario)
    reference = scenario.force_reference
    probe = reference.probe_amplitude_n != 0
    key += [("safety.enabled", bool(scenario.safety.enabled)),
            ("faults", tuple(f.signal for f in scenario.faults)),
            ("joint_friction.model", scenario.joint_friction.model),
            *((f"force_sensor.{f}", getattr(scenario.force_sensor, f))
              for f in SENSOR_STRUCTURE),
            ("dsp.anti_aliasing.mode", scenario.dsp.anti_aliasing.mode),
            ("force_reference.probe_amplitude_n", "on" if probe else "off"),
            ("force_reference.probe_frequencies_hz",
             len(reference.probe_frequencies_hz) if probe else 0)]
    return tuple((field, _hashable(value)) for field, value in key)


def identifiers_structure(scenario) -> tuple:
    """The identifiers' part of :func:`ensemble_structure`: their (name,
    kind, signals, chain_model), then what each one's options switch on."""
    key = [("identifiers", tuple((c.name, c.kind, c.signals, c.chain_model)
                                 for c in scenario.identifiers))]
    for k, config in enumerate(scenario.identifiers):
        declared = identifier_declaration(config.kind, f"identifiers[{k}].kind")
        key += _declared(declared, config.factory_options(scenario.simulation.seed),
                         f"identifiers[{k}]")
    return tuple((field, _hashable(value)) for field, value in key)


def first_difference(key, other):
    """The first ``(field, value in key, value in other)`` in which two
    structure keys differ, else None."""
    for (field, value), (other_field, other_value) in zip(key, other):
        if field != other_field:
            return field, value, "absent"
        if value != other_value:
            return field, value, other_value
    if len(key) != len(other):
        longer = key if len(key) > len(other) else other
        field, value = longer[min(len(key), len(other))]
        return (field, value, "absent") if longer is key else (field, "absent", value)
    return None


def check_ensemble_structure(scenarios, key=ensemble_structure):
    """Raises ScenarioError (one line) naming the first environment and
    field in which ``scenarios`` differ from environment 0's structure
    (``key``: :func:`ensemble_structure`, or a part of it such as
    :func:`identifiers_structure`); returns the shared key."""
    scenarios = list(scenarios)
    if not scenarios:
        raise ScenarioError("an ensemble needs at least one scenario")
    first = key(scenarios[0])
    for i, scenario in enumerate(scenarios[1:], start=1):
        found = first_difference(key(scenario), first)
        if found is not None:
            field, value, base = found
            raise ScenarioError(
                f"{field} = {value!r} in environment {i} is out of range: an ensemble's "
                f"environments share a structure ({base!r} in environment 0)")
    return first
