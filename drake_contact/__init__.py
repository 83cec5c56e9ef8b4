"""drake_contact: Kiguchi (1993) force control in contact with compliant
environments, reproduced as Drake systems-framework diagrams.

The public API, as a Drake user meets it::

    import drake_contact as dc
    scenario = dc.load_scenario("push_constant", seed=3)      # a name, a file or YAML text
    builder = DiagramBuilder()
    station = builder.AddSystem(dc.MakeContactDiagram(scenario))
    loggers = dc.AddSignalLoggers(builder, station)            # the run's logs
    ...                                                        # your systems, your loggers
    result = dc.simulate(builder.Build(), loggers)             # checks, logs, metrics

The library (:mod:`drake_contact.plant`, :mod:`.sensing`, :mod:`.control`,
:mod:`.identification`, :mod:`.scoring`, with :mod:`.scenario`,
:mod:`.diagram`, :mod:`.simulation` and :mod:`.visualization`: building,
simulating, logging, scoring and drawing a run) never imports the
application (:mod:`drake_contact.app`: run folders, plotting, reproduction,
sweeps, benchmark, fault study, CLI).
"""

import importlib

# The public names and the modules that define them. They are imported on
# first use (PEP 562), so ``import drake_contact`` (or a run's process) does
# not load matplotlib, graphviz or the metrics' scipy.stats unless asked:
# a run's resident memory is mostly its imports and its log.
_EXPORTS = {
    "drake_contact.app.drawing": ("write_diagram",),
    "drake_contact.scoring.metrics": ("compute_metrics",),
    "drake_contact.app.plotting": (
        "plot_force_tracking", "plot_impedance", "plot_signal", "plot_tip_errors"),
    "drake_contact.app.runner": ("run",),
    "drake_contact.simulation": (
        "AddSignalLoggers", "MakeRunDiagram", "RunResult", "SignalLoggers", "simulate",
        "simulate_scenario"),
    "drake_contact.diagram": ("ContactStation", "MakeContactDiagram", "SeedNoise", "Signal"),
    "drake_contact.structure": ("ensemble_structure",),
    "drake_contact.batching": ("assert_batched_equals_alone",),
    "drake_contact.errors": ("ScenarioError", "SimulationDiverged"),
    "drake_contact.control.safety_supervisor": ("SafetyConfig", "SafetySupervisor"),
    "drake_contact.faults": (
        "FAULT_KINDS", "AddFault", "FaultConfig", "FaultKind", "StudyCase", "register_fault_kind"),
    "drake_contact.measured": ("MeasuredSignals",),
    "drake_contact.plant.arm": ("ApplySampledUpdates", "CalcSampledUpdate"),
    "drake_contact.plugins": (
        "ContactDetector", "Declaration", "MakeController", "MakeIdentifier", "declare",
        "installed_controllers", "installed_identifiers", "typed_options"),
    "drake_contact.scenario": ("Scenario", "dump_scenario", "load_scenario"),
}
_MODULE_OF = {name: module for module, names in _EXPORTS.items() for name in names}


def __getattr__(name):
    module = _MODULE_OF.get(name)
    if module is None:
        raise AttributeError(f"module 'drake_contact' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later lookups skip __getattr__
    return value


def __dir__():
    return sorted(set(globals()) | set(_MODULE_OF))


__version__ = "0.1.0"

__all__ = [
    # Scenarios
    "Scenario", "load_scenario", "dump_scenario", "ScenarioError",
    # Building
    "MakeContactDiagram", "ContactStation", "Signal", "MeasuredSignals", "AddSignalLoggers",
    "SignalLoggers", "MakeRunDiagram", "write_diagram",
    # Ensembles: what N environments in one station must share, and the
    # check that a batched system gives each environment its run alone
    "ensemble_structure", "assert_batched_equals_alone",
    # Running
    "SeedNoise", "simulate", "simulate_scenario", "run", "RunResult", "SimulationDiverged",
    "compute_metrics",
    # Faults and the safety supervisor (scenario keys faults: and safety:)
    "FaultConfig", "FAULT_KINDS", "AddFault", "SafetyConfig", "SafetySupervisor",
    # A fault kind of your own: a FaultKind subclass under register_fault_kind
    "FaultKind", "StudyCase", "register_fault_kind",
    # Plug-in controllers and identifiers (entry points; see drake_contact.plugins)
    "MakeController", "MakeIdentifier", "installed_controllers", "installed_identifiers",
    "ContactDetector", "declare", "Declaration", "typed_options",
    # Testing one sampled system (controller, identifier) without a simulator
    "ApplySampledUpdates", "CalcSampledUpdate",
    # Plotting (on your own axes; no backend is set)
    "plot_force_tracking", "plot_tip_errors", "plot_impedance", "plot_signal",
]
