"""A safety supervisor between the controller and the motors (``safety:``).

Not in the thesis (its experiments had none; its scenarios leave it off).
It reads only what the controller reads (the DSP's force, the estimator's
joint and tip states), never the truth, and passes the controller's torque
through unless one of these acts, checked in this order every 1 ms:

1. **Safe stop** (latched: the run ends held still). Fires on a non-finite
   controller torque, a filtered force above ``force_limit_n`` for
   ``force_stop_samples`` samples, a tip speed above ``tip_speed_limit_m_s``
   (after ``speed_check_from_s``), or a force reading stuck (flagged, the
   settle not counted) longer than ``sensor_fault_stop_s``. The arm is held
   by a joint PD (``stop_stiffness``, ``stop_damping``) at the joint angles
   that put the tip ``stop_backoff_m`` back along -x from where it was
   then, the controller ignored from then on.
2. **Sensor fault**: the force reading is flagged as implausible by the
   :class:`drake_contact.control.force_monitor.ForceReadingMonitor` (from the
   first contact on: unchanged for ``sensor_frozen_samples`` samples, or a
   jump of more than ``sensor_jump_n`` repeated exactly; until it moves
   again and ``sensor_settle_samples`` more). The supervisor holds the arm
   where it was when the reading last moved: the torque it sent then, plus
   the joint PD of a stop around the joint angles of then (a blind
   controller would act on a reading that is not the force; a torque held
   without feedback lets the light wrist run away, 3 rad/s within 0.2 s,
   measured). The same flag (``force_fault``) holds the controller's and
   the identifiers' state, so that they resume from where they were.
3. **Contact loss** (``contact_loss: hold``, the default; ``approach``
   leaves it to the controller): after the first contact, a filtered force
   below ``contact_loss_force_n`` for ``contact_loss_time_s``. The arm is held by
   the joint PD where it was, until the measured force is back above
   ``contact_force_n`` (the surface came back to the held tip).
4. **Force reflex**: the filtered force above ``reflex_fraction`` of the
   limit. For ``reflex_hold_s`` after it was last above, the push the
   controller commands along x is clamped to ``reflex_push_fraction`` of
   the limit and ``reflex_damping_x`` of tip damping is added.
5. **Push clamp** (always, sensor-free): the normal force the controller's
   torque commands, F = J(q)^-T tau, is clamped along +x to
   ``push_clamp_fraction`` of the limit. A biased, scaled, saturated or dead
   sensor can make a force loop push without bound; the clamp bounds the
   push it commands (not what the wall's own dynamics add: a K_e that
   doubles doubles the force within the step).

Last, each joint's torque may change by at most ``torque_rate_limit`` (N m/s)
per sample (0: no limit). Every decision is logged as ``safety_state``
(:data:`SAFETY_STATES`).
"""

import dataclasses as dc
import math

import numpy as np
from pydrake.systems.framework import Diagram, DiagramBuilder, LeafSystem
from pydrake.systems.primitives import Demultiplexer, Multiplexer

from drake_contact.blocks import Layout
from drake_contact.constants import CONTACT_THRESHOLD_N
from drake_contact.control.force_monitor import ForceReadingMonitor
from drake_contact.errors import ScenarioError
from drake_contact.plant.arm import (
    CONTROL_PERIOD, TIME_TOLERANCE_S, DeclareSampledUpdate, is_sample_time)
from drake_contact.plant.planar_arm import solve3, tip_jacobian

#: safety_state values, in order of precedence (higher wins).
SAFETY_STATES = {0: "pass", 1: "push clamped", 2: "force reflex", 3: "contact-loss hold",
                 4: "sensor-fault hold", 5: "safe stop"}
PASS, CLAMPED, REFLEX, LOSS_HOLD, SENSOR_HOLD, STOPPED = range(6)
CONTACT_LOSS_REACTIONS = ("approach", "hold")


@dc.dataclass
class SafetyConfig:
    """The supervisor's limits and reactions (off unless ``enabled``). The
    limits also define a safe end of a run in the metrics, on or off."""

    # Put the supervisor between the controller and the motors.
    enabled: bool = False
    # The true normal force it guards (N), read from the measured force.
    force_limit_n: float = 60.0
    # The stop needs the filtered force over the limit this many samples in
    # a row (two 30 N spikes of a faulty sensor read 41 N through the
    # filter for one sample).
    force_stop_samples: int = 3
    # The reflex fires above this fraction of the limit (filtered force).
    reflex_fraction: float = 0.7
    # ... and lasts this long after the force was last above it (s).
    reflex_hold_s: float = 0.3
    # During a reflex, the commanded push along x is clamped to this
    # fraction of the limit, with this tip damping along x (N s/m) added.
    reflex_push_fraction: float = 0.4
    reflex_damping_x: float = 300.0
    # The commanded push along x is always clamped to this fraction of the
    # limit (sensor-free: from the torque and J(q)).
    push_clamp_fraction: float = 0.8
    # Tip speed (|xdot, ydot|, m/s) above which it stops the arm, checked
    # from speed_check_from_s on (the estimator's start-up transient reads
    # up to 43 m/s in its first 20 ms; the thesis's arm moves at up to
    # 0.22 m/s when it starts).
    tip_speed_limit_m_s: float = 0.5
    speed_check_from_s: float = 0.5
    # Largest torque change per joint (N m/s); 0 = no limit. (The thesis's
    # controllers change joints 1 and 2 by up to 2.2 N m in 1 ms.)
    torque_rate_limit: list[float] = dc.field(default_factory=lambda: [0.0, 0.0, 0.0])
    # A raw reading unchanged for this many 1 ms samples is a sensor fault
    # (0: the reading is never checked). The noise moves a live reading
    # every sample: on the bundled scenarios' golden runs, at most 1
    # sample in a row repeats, in contact.
    sensor_frozen_samples: int = 5
    # ... and so is a jump of more than this (N) in one sample that the next
    # sample repeats exactly (0: no jump rule). The noise's largest change
    # from one sample to the next is 4.2 N on the golden runs.
    sensor_jump_n: float = 8.0
    # The flag stays up this many samples after the reading moves again
    # (the 120 Hz filter's step response is within 1 % after 6 ms).
    sensor_settle_samples: int = 10
    # A reading stuck longer than this (s; from when it is flagged, the
    # settle not counted) ends in a safe stop.
    sensor_fault_stop_s: float = 1.0
    # After a contact loss: hold (joint PD where it was) or approach (the
    # controller's own approach). Hold measured: nn_robust back within 1 N
    # of f_d 0.10 s after a 5 mm, 0.5 s retreat of a 25 kN/m surface; 3.7 s
    # by its approach.
    contact_loss: str = "hold"
    # Contact: filtered force above this (N); lost: below this (N) for this long (s).
    contact_force_n: float = CONTACT_THRESHOLD_N
    contact_loss_force_n: float = 0.5
    contact_loss_time_s: float = 0.05
    # The joint PD of a hold or a stop (N m/rad, N m s/rad): about 5 Hz and
    # damping 0.7 on the arm's joint inertias at q0 (1.03, 0.117, 0.0029
    # kg m^2) for joints 1-2. Joint 3 must be stiffer than the wall's push
    # on link 3 turns it, a3 f: 3 N m/rad at 20 N, 6 at a 40 N limit (at
    # 2.8 N m/rad a 0.5 s sensor hold at 20 N let the wrist fold by 0.16 rad
    # and the force fall to 9.6 N, measured); 8 N m/rad (8 Hz) and damping 0.66.
    stop_stiffness: list[float] = dc.field(default_factory=lambda: [1000.0, 110.0, 8.0])
    stop_damping: list[float] = dc.field(default_factory=lambda: [45.0, 5.0, 0.2])
    # A stop holds the tip this far back from where it was (m): holding a
    # tip that was pushing past the limit where it was keeps pushing (34 N
    # against a 28 N limit when K_e jumps 1.5 times, measured; 30 N with
    # no supervisor at all).
    stop_backoff_m: float = 0.002

    def validate(self, prefix="safety"):
        def bad(field, value, allowed):
            raise ScenarioError(f"{prefix}.{field} = {value} is out of range: {allowed}")

        def finite(x):
            return isinstance(x, (int, float)) and math.isfinite(x)
        if not (finite(self.force_limit_n) and self.force_limit_n > 0):
            bad("force_limit_n", self.force_limit_n, "must be > 0 N")
        for field in ("reflex_fraction", "reflex_push_fraction", "push_clamp_fraction"):
            value = getattr(self, field)
            if not (finite(value) and 0 < value <= 1):
                bad(field, value, "must be in (0, 1]")
        for field in ("reflex_hold_s", "reflex_damping_x", "contact_loss_force_n",
                      "speed_check_from_s", "stop_backoff_m", "sensor_jump_n"):
            value = getattr(self, field)
            if not (finite(value) and value >= 0):
                bad(field, value, "must be >= 0")
        for field in ("tip_speed_limit_m_s", "sensor_fault_stop_s", "contact_force_n",
                      "contact_loss_time_s"):
            value = getattr(self, field)
            if not (finite(value) and value > 0):
                bad(field, value, "must be > 0")
        if not self.contact_loss_force_n < self.contact_force_n:
            bad("contact_loss_force_n", self.contact_loss_force_n,
                f"must be below contact_force_n = {self.contact_force_n} N")
        for field in ("sensor_frozen_samples", "sensor_settle_samples"):
            value = getattr(self, field)
            if not (isinstance(value, int) and not isinstance(value, bool) and value >= 0):
                bad(field, value, "must be an integer >= 0")
        if not (isinstance(self.force_stop_samples, int) and self.force_stop_samples >= 1):
            bad("force_stop_samples", self.force_stop_samples, "must be an integer >= 1")
        if self.contact_loss not in CONTACT_LOSS_REACTIONS:
            raise ScenarioError(f"{prefix}.contact_loss = '{self.contact_loss}' is unknown: "
                                f"choose one of {', '.join(CONTACT_LOSS_REACTIONS)}")
        for field in ("torque_rate_limit", "stop_stiffness", "stop_damping"):
            value = getattr(self, field)
            if len(value) != 3 or not all(finite(x) and x >= 0 for x in value):
                bad(field, value, "must be 3 values >= 0")


# The law's output and held state: [tau (3), safety_state, then memory].
_LAW = Layout(
    ("tau", 3), ("state", 1),
    ("q_hold", 3),             # joint angles a hold or stop holds (rad)
    ("tau_good", 3),           # torque sent when the reading last moved (N m)
    ("q_good", 3),             # joint angles when the reading last moved (rad)
    ("raw_prev", 1), ("armed", 1), ("reflex_t", 1), ("loss_t", 1),
    ("fault_t", 1), ("over", 1), ("reason", 1))
_TAU, _STATE, _Q_HOLD, _TAU_GOOD, _Q_GOOD = (_LAW.tau, _LAW.state, _LAW.q_hold, _LAW.tau_good,
                                             _LAW.q_good)
_RAW_PREV, _ARMED, _REFLEX_T, _LOSS_T, _FAULT_T, _OVER, _REASON = (
    _LAW.raw_prev, _LAW.armed, _LAW.reflex_t, _LAW.loss_t, _LAW.fault_t, _LAW.over,
    _LAW.reason)
_LAW_SIZE = _LAW.size
#: Why the safe stop fired (the ``safety_stop_reason`` output), and its words.
STOP_NONE, STOP_TORQUE_NOT_FINITE, STOP_FORCE_LIMIT, STOP_TIP_SPEED, STOP_SENSOR_FAULT = range(5)
STOP_REASONS = {STOP_NONE: "none", STOP_TORQUE_NOT_FINITE: "non-finite controller torque",
                STOP_FORCE_LIMIT: "measured force over the limit",
                STOP_TIP_SPEED: "tip speed over the limit",
                STOP_SENSOR_FAULT: "sensor fault too long"}


class SafetySupervisorLaw(LeafSystem):
    """The supervisor's law as one leaf: output ``law`` (21) is evaluated at
    each 1 ms sample from the inputs and held between, the sample's update
    stores it (as :class:`drake_contact.control.hybrid_controller.HybridControlLaw`).

    Input ports: joint_torque_commanded (3, N m), force (1, filtered, N),
    force_raw (1, N), joint_positions (3, rad), joint_velocities (3,
    rad/s), tip_velocity (3, m/s, rad/s), force_monitor (2, the monitor's
    output: [the flag, whether the reading is stuck now]).
    Output port: law (20): [tau (3, N m), safety_state, memory (15), stop reason].
    """

    def __init__(self, config: SafetyConfig):
        super().__init__()
        config.validate()
        self._config = config
        # Per-sample constants, as arrays once rather than every sample.
        self._kp = np.asarray(config.stop_stiffness, dtype=float)
        self._kd = np.asarray(config.stop_damping, dtype=float)
        rate = np.asarray(config.torque_rate_limit, dtype=float) * CONTROL_PERIOD
        self._rate_per_sample = rate if np.any(rate > 0) else None
        self._tau = self.DeclareVectorInputPort("joint_torque_commanded", 3)
        self._force = self.DeclareVectorInputPort("force", 1)
        self._force_raw = self.DeclareVectorInputPort("force_raw", 1)
        self._q = self.DeclareVectorInputPort("joint_positions", 3)
        self._qdot = self.DeclareVectorInputPort("joint_velocities", 3)
        self._v_tip = self.DeclareVectorInputPort("tip_velocity", 3)
        self._monitor = self.DeclareVectorInputPort("force_monitor", 2)
        held = np.zeros(_LAW_SIZE)
        held[[_REFLEX_T, _LOSS_T, _FAULT_T]] = -np.inf
        held[_RAW_PREV] = np.nan
        self._held = self.DeclareDiscreteState(held)
        self._law = self.DeclareVectorOutputPort(
            "law", _LAW_SIZE, self._calc_law,
            prerequisites_of_calc={self.all_input_ports_ticket(), self.xd_ticket(),
                                   self.time_ticket()})
        DeclareSampledUpdate(self, self._update)

    def _update(self, context, state):
        state.set_value(self._law.Eval(context))

    def _calc_law(self, context, output):
        held = context.get_discrete_state(self._held).value()
        t = context.get_time()
        if not is_sample_time(t):
            output.SetFromVector(held)
            return
        out = held.copy()
        c = self._config
        tau_cmd = self._tau.Eval(context)
        f = float(self._force.Eval(context)[0])
        raw = float(self._force_raw.Eval(context)[0])
        q = self._q.Eval(context)
        qdot = self._qdot.Eval(context)
        v = self._v_tip.Eval(context)
        limit = c.force_limit_n

        armed = held[_ARMED] > 0 or f > c.contact_force_n
        # Sensor: the monitor's flag; the torque and angles of the last
        # sample the reading moved.
        if raw != held[_RAW_PREV]:
            out[_TAU_GOOD] = held[_TAU]
            out[_Q_GOOD] = q
        flag, stuck = self._monitor.Eval(context)
        sensor_fault = flag > 0
        # How long the reading has been stuck (the flag's settle samples
        # after it moves again are not the sensor's fault).
        fault_t = held[_FAULT_T]
        if stuck > 0 and fault_t == -np.inf:
            fault_t = t
        elif not stuck > 0:
            fault_t = -np.inf
        # Contact loss timer.
        loss_t = held[_LOSS_T]
        if armed and f < c.contact_loss_force_n:
            loss_t = t if loss_t == -np.inf else loss_t
        elif f > c.contact_force_n:
            loss_t = -np.inf
        # Reflex: last time the force was above the reflex level.
        reflex_t = t if f > c.reflex_fraction * limit else held[_REFLEX_T]

        over = held[_OVER] + 1 if f > limit else 0
        state = int(held[_STATE])
        reason = int(held[_REASON])
        if state != STOPPED:
            reason = self._stop_reason(tau_cmd, over, t, v, stuck > 0 and t - fault_t)
        if reason:
            if state != STOPPED:
                # Hold the joint angles that put the tip stop_backoff_m back
                # along -x (to first order: dq = J^-1 dx).
                dq = solve3(tip_jacobian([float(x) for x in q]), [-c.stop_backoff_m, 0.0, 0.0])
                out[_Q_HOLD] = q + np.array(dq)
            state = STOPPED
            tau = self._pd(out[_Q_HOLD], q, qdot)
        elif sensor_fault:
            state = SENSOR_HOLD
            tau = out[_TAU_GOOD] + self._pd(out[_Q_GOOD], q, qdot)
        elif c.contact_loss == "hold" and (state == LOSS_HOLD and f <= c.contact_force_n or
                                           loss_t > -np.inf and
                                           t - loss_t >= c.contact_loss_time_s - TIME_TOLERANCE_S):
            if state != LOSS_HOLD:
                out[_Q_HOLD] = q
            state = LOSS_HOLD
            loss_t = -np.inf
            tau = self._pd(out[_Q_HOLD], q, qdot)
        else:
            tau, state = self._push_limited(tau_cmd, q, v, t - reflex_t)
        out[_TAU] = self._rate_limited(tau, held[_TAU], t)
        out[_STATE] = state
        out[_RAW_PREV] = raw
        out[_ARMED] = float(armed)
        out[_REFLEX_T] = reflex_t
        out[_LOSS_T] = loss_t
        out[_FAULT_T] = fault_t
        out[_OVER] = over
        out[_REASON] = reason
        output.SetFromVector(out)

    def _stop_reason(self, tau_cmd, over, t, v, sensor_fault_for):
        """Why the arm stops now (STOP_NONE: it does not): a torque that is not
        finite, the force over the limit for ``over`` samples, the tip too
        fast, or a sensor fault for ``sensor_fault_for`` s (False: none)."""
        c = self._config
        if not np.all(np.isfinite(tau_cmd)):
            return STOP_TORQUE_NOT_FINITE
        if over >= c.force_stop_samples:
            return STOP_FORCE_LIMIT
        if t >= c.speed_check_from_s and math.hypot(v[0], v[1]) > c.tip_speed_limit_m_s:
            return STOP_TIP_SPEED
        if sensor_fault_for is not False \
                and sensor_fault_for >= c.sensor_fault_stop_s - TIME_TOLERANCE_S:
            return STOP_SENSOR_FAULT
        return STOP_NONE

    def _rate_limited(self, tau, tau_before, t):
        """``tau`` moved at most the rate limit per sample from the last
        sample's torque (the first sample is not limited)."""
        rate = self._rate_per_sample
        if rate is None or t <= CONTROL_PERIOD / 2:
            return tau
        step = np.where(rate > 0, np.clip(tau - tau_before, -rate, rate), tau - tau_before)
        return tau_before + step

    def _push_limited(self, tau_cmd, q, v, since_reflex):
        """The commanded torque with the tip's push along x clamped, and
        within ``reflex_hold_s`` of a force over the reflex level
        (``since_reflex`` ago) damped and clamped lower; and the state
        that says which (PASS, CLAMPED or REFLEX)."""
        c = self._config
        reflex = since_reflex <= c.reflex_hold_s + TIME_TOLERANCE_S
        push_max = (c.reflex_push_fraction if reflex else c.push_clamp_fraction) * c.force_limit_n
        J = tip_jacobian([float(x) for x in q])
        # F = J^-T tau: solve J^T F = tau.
        JT = [[J[r][k] for r in range(3)] for k in range(3)]
        F = solve3(JT, [float(x) for x in tau_cmd])
        if reflex:
            F[0] -= c.reflex_damping_x * float(v[0])
        clamped = F[0] > push_max
        if clamped:
            F[0] = push_max
        if reflex or clamped:
            tau = np.array([sum(J[r][k] * F[r] for r in range(3)) for k in range(3)])
        else:
            tau = np.array(tau_cmd, dtype=float)
        return tau, REFLEX if reflex else CLAMPED if clamped else PASS

    def _pd(self, q_hold, q, qdot):
        """The joint PD of a hold or a stop about ``q_hold``."""
        return self._kp * (q_hold - q) - self._kd * qdot


class SafetySupervisor(Diagram):
    """The supervisor: the force reading's monitor
    (:class:`drake_contact.control.force_monitor.ForceReadingMonitor`),
    :class:`SafetySupervisorLaw` and Demultiplexers.

    Input ports: those of the law but ``force_monitor`` (the monitor's).
    Output ports: ``joint_torque`` (3, N m, to the torque saturation),
    ``safety_state`` (1, :data:`SAFETY_STATES`), ``safety_stop_reason`` (1,
    :data:`STOP_REASONS`) and ``force_fault`` (1: the monitor's flag, which
    depends on the force inputs only: the controller and its identifiers
    read it in the same sample).
    """

    def __init__(self, config: SafetyConfig):
        super().__init__()
        builder = DiagramBuilder()
        law = builder.AddNamedSystem("law", SafetySupervisorLaw(config))
        monitor = builder.AddNamedSystem("force_monitor", ForceReadingMonitor(config))
        readings = builder.AddNamedSystem("force_monitor_inputs", Multiplexer(2))
        builder.Connect(readings.get_output_port(), monitor.get_input_port())
        builder.Connect(monitor.get_output_port(), law.GetInputPort("force_monitor"))
        flag = builder.AddNamedSystem("force_monitor_outputs", Demultiplexer(2, 1))
        builder.Connect(monitor.get_output_port(), flag.get_input_port())
        memory = _LAW.span("q_hold", "over")
        split = builder.AddNamedSystem(
            "outputs", Demultiplexer([3, 1, memory.stop - memory.start, 1]))
        builder.Connect(law.get_output_port(), split.get_input_port())
        for i in range(law.num_input_ports()):
            port = law.get_input_port(i)
            if port.get_name() == "force_monitor":
                continue
            index = builder.ExportInput(port, port.get_name())
            if port.get_name() in ("force_raw", "force"):  # the monitor's [raw, filtered]
                builder.ConnectInput(
                    index, readings.get_input_port(0 if port.get_name() == "force_raw" else 1))
        builder.ExportOutput(split.get_output_port(0), "joint_torque")
        builder.ExportOutput(split.get_output_port(1), "safety_state")
        builder.ExportOutput(split.get_output_port(3), "safety_stop_reason")
        builder.ExportOutput(flag.get_output_port(0), "force_fault")
        builder.BuildInto(self)
