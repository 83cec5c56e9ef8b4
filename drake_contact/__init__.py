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

The library layers (:mod:`drake_contact.plant`, :mod:`.sensing`,
:mod:`.control`, :mod:`.identification`, with :mod:`.scenario` and
:mod:`.diagram`) never import the application (:mod:`drake_contact.app`:
runner, metrics, plotting, visualization, reproduction, benchmark, CLI).
"""

from drake_contact.app.drawing import write_diagram
from drake_contact.app.metrics import compute_metrics
from drake_contact.app.plotting import (
    plot_force_tracking, plot_impedance, plot_signal, plot_tip_errors)
from drake_contact.app.runner import (
    AddSignalLoggers, MakeRunDiagram, RunResult, SignalLoggers, run, simulate, simulate_scenario)
from drake_contact.diagram import ContactStation, MakeContactDiagram, SeedNoise, Signal
from drake_contact.errors import ScenarioError, SimulationDiverged
from drake_contact.control.safety_supervisor import SafetyConfig, SafetySupervisor
from drake_contact.faults import FAULT_KINDS, AddFault, FaultConfig
from drake_contact.measured import MeasuredSignals
from drake_contact.plant.arm import ApplySampledUpdates, CalcSampledUpdate
from drake_contact.plugins import (
    ContactDetector, MakeController, MakeIdentifier, installed_controllers, installed_identifiers)
from drake_contact.scenario import Scenario, dump_scenario, load_scenario

__version__ = "0.1.0"

__all__ = [
    # Scenarios
    "Scenario", "load_scenario", "dump_scenario", "ScenarioError",
    # Building
    "MakeContactDiagram", "ContactStation", "Signal", "MeasuredSignals", "AddSignalLoggers",
    "SignalLoggers", "MakeRunDiagram", "write_diagram",
    # Running
    "SeedNoise", "simulate", "simulate_scenario", "run", "RunResult", "SimulationDiverged",
    "compute_metrics",
    # Faults and the safety supervisor (scenario keys faults: and safety:)
    "FaultConfig", "FAULT_KINDS", "AddFault", "SafetyConfig", "SafetySupervisor",
    # Plug-in controllers and identifiers (entry points; see drake_contact.plugins)
    "MakeController", "MakeIdentifier", "installed_controllers", "installed_identifiers",
    "ContactDetector",
    # Testing one sampled system (controller, identifier) without a simulator
    "ApplySampledUpdates", "CalcSampledUpdate",
    # Plotting (on your own axes; no backend is set)
    "plot_force_tracking", "plot_tip_errors", "plot_impedance", "plot_signal",
]
