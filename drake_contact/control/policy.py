"""A learned policy on top of the thesis's hybrid law: the ``policy``
controller.

The policy sees the measured signals (:data:`~drake_contact.control.policy_spaces.OBSERVATION`)
and every ``period_ms`` commands a residual on the hybrid law's force and
scales of its gains (:data:`~drake_contact.control.policy_spaces.ACTION`);
the law runs every 1 ms with the latest action. The policy is any callable
from the observation (a float64 vector) to the action (4 numbers):

- ``policy.source: ''``: the zero action, the hybrid law unmodified;
- ``policy.source: 'package.module:name'``: ``name`` is the callable, or a
  function of no arguments that returns it (a factory, e.g. one that loads
  saved weights);
- ``policy.source: 'path/to/policy.json'`` (or .npz): a :class:`NumpyPolicy`;
- ``policy.source: external``: the action comes from the station's input
  port ``policy_action`` (the Gymnasium environment, :mod:`drake_contact.gym`).

Observation and action are computed by the same systems in a scenario, in
the benchmark and in the Gymnasium environment, so a policy trained there
runs here unchanged, and a rollout of the environment equals the run of
the same policy here, log for log.
"""

import dataclasses as dc
import importlib
import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
from pydrake.systems.framework import Diagram, DiagramBuilder, LeafSystem
from pydrake.systems.primitives import ConstantVectorSource

from drake_contact.control.hybrid_controller import (
    _LAW, APPROACH, HybridController, HybridControllerConfig, _gather, structure)
from drake_contact.arm_axis import arm_axis_ops
from drake_contact.control.policy_spaces import ACTION, OBSERVATION, check_action, observation
from drake_contact.errors import ScenarioError, SimulationDiverged, require_finite
from drake_contact.measured import by_role
from drake_contact.options import config_from_options
from drake_contact.plant.arm import CONTROL_PERIOD, DeclareSampledUpdate, is_sample_time
from drake_contact.plugins import declare

#: ``policy.source`` of a policy whose action is the station's input port.
EXTERNAL = "external"


@dc.dataclass
class PolicyConfig:
    """The policy of the ``policy`` controller (see :mod:`drake_contact.control.policy`)."""

    # '' (the zero action: the hybrid law unmodified), 'module:name' (a
    # callable observation -> action, or a factory of one), a .json or .npz
    # file of a NumpyPolicy, or 'external' (the station's policy_action input).
    source: str = ""
    # The policy acts every this many 1 ms samples (its control period).
    period_ms: int = 10

    def validate(self, prefix="controller.policy"):
        if not (isinstance(self.period_ms, int) and 1 <= self.period_ms <= 1000):
            raise ScenarioError(f"{prefix}.period_ms = {self.period_ms} is out of range: must "
                                "be an integer in [1, 1000] (ms)")
        source = self.source
        if source in ("", EXTERNAL):
            return
        if source.endswith((".npz", ".json")):
            if not Path(source).is_file():
                raise ScenarioError(f"{prefix}.source = '{source}': no such file")
        elif ":" not in source:
            raise ScenarioError(f"{prefix}.source = '{source}' is not '', 'external', a .json "
                                "or .npz file or 'module:name'")


#: How a NumpyPolicy's last layer gives an action within [-1, 1]: through
#: tanh (a squashed policy: CMA-ES's), or clipped (the mean of a Gaussian
#: policy, clipped to the action space as Stable-Baselines3's PPO does).
OUTPUTS = ("tanh", "clip")


class NumpyPolicy:
    """A small network in numpy: tanh hidden layers and an output through
    tanh or clipped (``output``, :data:`OUTPUTS`), so its action is within
    [-1, 1]. ``layers`` is [(W, b), ...], W of shape (outputs, inputs); no
    hidden layer is a linear policy. Its input is one observation (10) or a
    batch of them (n x 10: then n actions)."""

    def __init__(self, layers, output="tanh"):
        self.layers = [(np.asarray(w, dtype=float), np.asarray(b, dtype=float))
                       for w, b in layers]
        if output not in OUTPUTS:
            raise ValueError(f"output = {output!r}: choose one of {', '.join(OUTPUTS)}")
        self.output = output
        if self.layers[0][0].shape[1] != OBSERVATION.size or \
                self.layers[-1][0].shape[0] != ACTION.size:
            raise ValueError(f"a NumpyPolicy maps {OBSERVATION.size} observations to "
                             f"{ACTION.size} actions; got {self.layers[0][0].shape[1]} -> "
                             f"{self.layers[-1][0].shape[0]}")

    def __call__(self, observation):
        h = np.asarray(observation, dtype=float).T
        last = len(self.layers) - 1
        for i, (w, b) in enumerate(self.layers):
            h = w @ h + (b if h.ndim == 1 else b[:, None])
            if i < last or self.output == "tanh":
                h = np.tanh(h)
        if self.output == "clip":
            h = np.clip(h, -1.0, 1.0)
        return h.T

    def save(self, path, **about):
        """Writes the layers to ``path``: .json (text, with ``about``: how it
        was trained) or .npz."""
        path = Path(path)
        if path.suffix == ".json":
            layers = [{"W": w.tolist(), "b": b.tolist()} for w, b in self.layers]
            data = {"layers": layers} | ({"output": self.output} if self.output != "tanh"
                                         else {})
            path.write_text(json.dumps(data | {"about": about}, indent=1) + "\n")
            return
        arrays = {"output": np.array(self.output)}
        for i, (w, b) in enumerate(self.layers):
            arrays[f"W{i}"], arrays[f"b{i}"] = w, b
        np.savez(path, **arrays)

    @classmethod
    def load(cls, path):
        """A policy saved by :meth:`save` (.json or .npz)."""
        path = Path(path)
        if path.suffix == ".json":
            data = json.loads(path.read_text())
            return cls([(layer["W"], layer["b"]) for layer in data["layers"]],
                       data.get("output", "tanh"))
        with np.load(path) as data:
            count = len([k for k in data.files if k.startswith("W")])
            output = str(data["output"]) if "output" in data.files else "tanh"
            return cls([(data[f"W{i}"], data[f"b{i}"]) for i in range(count)], output)


def zero_policy(observation):
    """The zero action: the hybrid law unmodified."""
    return np.zeros(ACTION.size)


def load_policy(source: str, prefix="controller.policy.source"):
    """The callable ``source`` names (see :class:`PolicyConfig`);
    ScenarioError naming ``prefix`` if it cannot be had."""
    if source == "":
        return zero_policy
    if source.endswith((".npz", ".json")):
        try:
            return NumpyPolicy.load(source)
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise ScenarioError(f"{prefix} = '{source}' is not a NumpyPolicy: {e}") from None
    module_name, _, name = source.partition(":")
    try:
        found = getattr(importlib.import_module(module_name), name)
    except (ImportError, AttributeError) as e:
        raise ScenarioError(f"{prefix} = '{source}' could not be loaded: "
                            f"{type(e).__name__}: {e}") from None
    if isinstance(found, type) or getattr(found, "is_policy_factory", False):
        found = found()
    if not callable(found):
        raise ScenarioError(f"{prefix} = '{source}' is not callable")
    return found


def policy_factory(function):
    """Marks ``function`` (no arguments) as returning the policy, so a
    ``module:name`` source calls it once to get the policy (e.g. to load
    weights) instead of taking it as the policy."""
    function.is_policy_factory = True
    return function


class PolicyObservation(LeafSystem):
    """The policy's observation (:data:`OBSERVATION`) from the measured
    signals and the law's held output, at each 1 ms sample (held between),
    for N environments (``y_desired``, ``phi_desired``: a number each for
    one, a sequence for N).

    Inputs (env-major): tip_pose (3 N), tip_velocity (3 N), force (N),
    force_desired (N), law_held (the hybrid law's previous output, laid out
    as the law's for N). Output: observation (10 N) (and next_state, the
    state after this sample, which the update stores). Its state, per
    environment: the sum of |f_d - f| since the last period boundary, how
    many samples it holds, the previous sample's force, and the
    observation. One environment runs on Python floats and stops the run
    on a non-finite observation; N run on arrays (N,), each row bit for bit
    its environment's alone, a diverging environment's values its own
    (the station reports it)."""

    def __init__(self, period_ms: int, y_desired, phi_desired):
        super().__init__()
        self._count = count = int(np.size(y_desired))
        self._ops = arm_axis_ops(count)
        self._period = period_ms
        self._targets = (y_desired, phi_desired) if count == 1 else (
            np.asarray(y_desired, dtype=float), np.asarray(phi_desired, dtype=float))
        self._pose = self.DeclareVectorInputPort("tip_pose", 3 * count)
        self._velocity = self.DeclareVectorInputPort("tip_velocity", 3 * count)
        self._force = self.DeclareVectorInputPort("force", count)
        self._force_desired = self.DeclareVectorInputPort("force_desired", count)
        self._law = self.DeclareVectorInputPort("law_held", _LAW.size * count)
        self._gather = _gather(count)
        self._state = self.DeclareDiscreteState(_STATE_SIZE * count)
        ticket = {self.all_input_ports_ticket(), self.xd_ticket(), self.time_ticket()}
        # The state after this sample (held between samples): computed once
        # per sample, cached, read by the observation and by the update.
        self._next = self.DeclareVectorOutputPort(
            "next_state", _STATE_SIZE * count, self._calc_next, prerequisites_of_calc=ticket)
        self.DeclareVectorOutputPort(
            "observation", OBSERVATION.size * count,
            lambda context, output: output.SetFromVector(
                self._next.Eval(context).reshape(count, _STATE_SIZE)[:, 3:].reshape(-1)),
            prerequisites_of_calc=ticket)
        DeclareSampledUpdate(self, lambda context, state: state.set_value(
            self._next.Eval(context)))

    def _calc_next(self, context, output):
        held = context.get_discrete_state(self._state).value()
        t = context.get_time()
        if not is_sample_time(t):
            output.SetFromVector(held)
            return
        n, ops = self._count, self._ops
        pose = self._pose.Eval(context)
        law = self._law.Eval(context)
        if n == 1:
            error_sum, count, force_previous = held[:3].tolist()
            f = self._force.Eval(context)[0]
            f_d = self._force_desired.Eval(context)[0]
            velocity_x, y, phi = self._velocity.Eval(context)[0], pose[1], pose[2]
            mode, first_contact = law[_LAW.mode], law[_LAW.info][0]
        else:
            rows = held.reshape(n, _STATE_SIZE)
            error_sum, count, force_previous = rows[:, 0], rows[:, 1], rows[:, 2]
            f = self._force.Eval(context)
            f_d = self._force_desired.Eval(context)
            velocity_x, y, phi = self._velocity.Eval(context)[0::3], pose[1::3], pose[2::3]
            law = law[self._gather]
            mode, first_contact = law[_LAW.mode], law[_LAW.info.start]
        error = abs(f_d - f)
        mean = (error_sum + error) / (count + 1.0)
        values = observation(
            f_d, f, force_previous, mean, velocity_x, y - self._targets[0],
            phi - self._targets[1], ops.where(mode == APPROACH, 0.0, 1.0),
            ops.where(first_contact >= 0.0, t - first_contact, 0.0), ops)
        boundary = round(t / CONTROL_PERIOD) % self._period == 0
        state = [ops.where(boundary, 0.0, error_sum + error),
                 ops.where(boundary, 0.0, count + 1.0), f]
        if n == 1:
            require_finite(np.array(values), context, "controller/policy_observation",
                           "the policy's observation")
            output.SetFromVector(state + values)
        else:
            output.SetFromVector(np.column_stack(state + values).reshape(-1))


#: The observation system's state per environment: the error sum, its
#: count, the previous force, then the observation.
_STATE_SIZE = 3 + OBSERVATION.size


class PolicyRunner(LeafSystem):
    """Calls each environment's policy on its observation every
    ``period_ms`` samples and holds its action (checked: ACTION.size finite
    numbers) until the next; the action at a boundary acts from that
    sample on. ``policies``: one callable, or a list of N (one per
    environment, each called on its own row).

    Input: observation (10 N). Output: policy_action (4 N); env-major."""

    def __init__(self, policies, period_ms: int):
        super().__init__()
        self._policies = list(policies) if isinstance(policies, (list, tuple)) else [policies]
        count = len(self._policies)
        self._period = period_ms
        self._observation = self.DeclareVectorInputPort("observation", OBSERVATION.size * count)
        self._held = self.DeclareDiscreteState(ACTION.size * count)
        self._output = self.DeclareVectorOutputPort(
            "policy_action", ACTION.size * count, self._calc,
            prerequisites_of_calc={self.all_input_ports_ticket(), self.xd_ticket(),
                                   self.time_ticket()})
        DeclareSampledUpdate(self, lambda context, state: state.set_value(
            self._output.Eval(context)))

    def _calc(self, context, output):
        t = context.get_time()
        if not (is_sample_time(t) and round(t / CONTROL_PERIOD) % self._period == 0):
            output.SetFromVector(context.get_discrete_state(self._held).value())
            return
        rows = self._observation.Eval(context).reshape(len(self._policies), OBSERVATION.size)
        where = "the policy's action"
        try:
            actions = [check_action(policy(row.copy()), where if len(rows) == 1 else
                                    f"environment {i}'s policy's action")
                       for i, (policy, row) in enumerate(zip(self._policies, rows))]
        except ValueError as e:
            raise SimulationDiverged(f"stopped at t = {t:.3f} s: {e} (controller/policy)",
                                     time_s=t, where="controller/policy") from None
        output.SetFromVector(np.concatenate(actions))


@dc.dataclass
class PolicyControllerOptions:
    """Options of the ``policy`` controller: its hybrid law and its policy."""

    hybrid: HybridControllerConfig = dc.field(default_factory=HybridControllerConfig)
    policy: PolicyConfig = dc.field(default_factory=PolicyConfig)


class PolicyController(Diagram):
    """The thesis's hybrid controller driven by a policy: the law
    (:class:`HybridController` with its ``policy_action`` input), the
    observation (:class:`PolicyObservation`) and, unless the policy is
    external, the :class:`PolicyRunner` calling ``policy``. For N
    environments: ``hybrid`` a list of N configs and ``policy`` None (each
    loaded from ``config.source``) or a list of N callables; one system
    of each kind serves all N, every port env-major.

    Inputs: the hybrid controller's measured ones and force_desired, and
    with an external policy policy_action (4 N). Outputs: as the hybrid
    controller's, plus policy_observation (10 N) and policy_action (4 N,
    not with an external policy: the station's input is the action)."""

    def __init__(self, hybrid: HybridControllerConfig | list, config: PolicyConfig, policy=None):
        super().__init__()
        configs = hybrid if isinstance(hybrid, list) else [hybrid]
        count = len(configs)
        builder = DiagramBuilder()
        law = builder.AddNamedSystem("hybrid", HybridController(hybrid, action_input=True))
        station = by_role()
        for role in ("tip_pose", "tip_velocity", "joint_positions", "joint_velocities", "force"):
            builder.ExportInput(law.GetInputPort(role), station[role])
        for name in ("force_desired", "force_fault"):
            builder.ExportInput(law.GetInputPort(name), name)
        stiffness = builder.AddNamedSystem(
            "stiffness_estimate", ConstantVectorSource([c.stiffness_estimate for c in configs]))
        builder.Connect(stiffness.get_output_port(), law.GetInputPort("stiffness_estimate"))
        targets = ((configs[0].y_desired, configs[0].phi_desired) if count == 1 else
                   ([c.y_desired for c in configs], [c.phi_desired for c in configs]))
        watch = builder.AddNamedSystem(
            "observation", PolicyObservation(config.period_ms, *targets))
        for role in ("tip_pose", "tip_velocity", "force"):
            builder.ConnectInput(station[role], watch.GetInputPort(role))
        builder.ConnectInput("force_desired", watch.GetInputPort("force_desired"))
        builder.Connect(law.GetOutputPort("held"), watch.GetInputPort("law_held"))
        if config.source == EXTERNAL:
            builder.ExportInput(law.GetInputPort("policy_action"), "policy_action")
        else:
            if policy is None:
                policy = load_policy(config.source)
            policies = policy if isinstance(policy, list) else [policy] * count
            runner = builder.AddNamedSystem("policy", PolicyRunner(policies, config.period_ms))
            builder.Connect(watch.GetOutputPort("observation"), runner.get_input_port())
            builder.Connect(runner.get_output_port(), law.GetInputPort("policy_action"))
            builder.ExportOutput(runner.get_output_port(), "policy_action")
        builder.ExportOutput(watch.GetOutputPort("observation"), "policy_observation")
        for name in ("joint_torque_commanded", "mode", "contact_info", "tip_jacobian"):
            builder.ExportOutput(law.GetOutputPort(name), name)
        builder.BuildInto(self)


def _policy_structure(options: dict) -> dict:
    """What an ensemble's environments share: the hybrid law's switches,
    the policy's period, and whether its action comes from outside
    (``options``: the sections as mappings, as the station passes them)."""
    policy = PolicyConfig(**options["policy"])
    return {f"hybrid.{field}": value
            for field, value in structure(SimpleNamespace(**options["hybrid"])).items()} | {
        "policy.period_ms": policy.period_ms, "policy.external": policy.source == EXTERNAL}


@declare(sections=("hybrid", "policy"), contender=False, unlogged=("tip_jacobian",),
         ensemble=True, structure=_policy_structure, signals={
    "policy_observation": "the policy's observation (drake_contact.control.policy_spaces."
                          "OBSERVATION_FIELDS: each signal over its scale)",
    "policy_action": "the policy's action [force_residual, force_gain_scale, "
                     "integral_gain_scale, damping_x], each in [-1, 1] before clipping"})
def policy(options: dict | list):
    """The hybrid law driven by a policy; options: ``hybrid`` (the fields of
    :class:`HybridControllerConfig`, law hybrid) and ``policy`` (of
    :class:`PolicyConfig`); a list of them: one system serving an
    ensemble's environments (each its own policy)."""
    configs = [config_from_options(PolicyControllerOptions, o, "controller")
               for o in (options if isinstance(options, list) else [options])]
    for config in configs:
        config.hybrid.validate("controller.hybrid")
        if config.hybrid.law != "hybrid":
            raise ScenarioError(f"controller.hybrid.law = '{config.hybrid.law}': the policy "
                                "controller acts on the hybrid law: choose law: hybrid")
        config.policy.validate("controller.policy")
    if not isinstance(options, list):
        return PolicyController(configs[0].hybrid, configs[0].policy)
    first = configs[0].policy
    policies = None if first.source == EXTERNAL else [
        load_policy(c.policy.source) for c in configs]
    return PolicyController([c.hybrid for c in configs], first, policies)
