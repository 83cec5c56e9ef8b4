"""The built-in fault kinds, in the order scenarios' errors and the fault
study list them. Each is a :class:`~drake_contact.faults.base.FaultKind`:
its class docstring says what ``magnitude`` means."""

import math

from pydrake.symbolic import Variable, floor, if_then_else, logical_and
from pydrake.symbolic import max as sym_max, min as sym_min

from drake_contact.faults.base import FaultKind, StudyCase, register_fault_kind
from drake_contact.plant.arm import CONTROL_PERIOD, TIME_TOLERANCE_S


class _NoMagnitude(FaultKind):
    """A kind whose magnitude is unused (0)."""
    allowed = "unused: 0"

    def magnitude_ok(self, m):
        return m == 0


@register_fault_kind
class ForceDropoutZero(_NoMagnitude):
    """The force reading is 0 N (magnitude unused, 0)."""
    name, signal = "force_dropout_zero", "force"
    study_case = StudyCase("dropout_zero_50ms", "the sensor reads 0 N for 50 ms",
                           {"duration_s": 0.05})

    def corrupt(self, law):
        law.y = [if_then_else(law.on, 0.0, v) for v in law.u]


def _hold(law, indices):
    """The signal's ``indices`` held at their last value before the fault
    while it is on."""
    held = {i: Variable(f"held_{i}") for i in indices}
    law.state = list(held.values())
    law.dynamics = [if_then_else(law.on, held[i], law.u[i]) for i in indices]
    for i in indices:
        law.y[i] = if_then_else(law.on, held[i], law.u[i])


@register_fault_kind
class ForceDropoutHold(_NoMagnitude):
    """The force reading stays at its last value (magnitude unused, 0)."""
    name, signal = "force_dropout_hold", "force"
    study_case = StudyCase("dropout_hold_500ms", "the reading freezes at its last value for 0.5 s",
                           {"duration_s": 0.5})

    def corrupt(self, law):
        _hold(law, range(len(law.u)))


@register_fault_kind
class ForceSpikes(FaultKind):
    """Spikes of height magnitude (N), sign random, at ``rate_hz`` on average."""
    name, signal, allowed = "force_spikes", "force", "spike height in N, finite and != 0"
    study_case = StudyCase("spikes", "30 N spikes at 50 Hz for 1 s",
                           {"duration_s": 1.0, "magnitude": 30.0, "rate_hz": 50.0})

    def magnitude_ok(self, m):
        return math.isfinite(m) and m != 0

    def corrupt(self, law):
        draw, sign = law.noise()
        m = law.fault.magnitude
        p = law.fault.rate_hz * CONTROL_PERIOD
        spike = if_then_else(logical_and(law.on, draw < p),
                             if_then_else(sign < 0.5, -m, m), 0.0)
        law.y = [v + spike for v in law.u]


@register_fault_kind
class ForceBias(FaultKind):
    """An offset of magnitude (N) added to the reading."""
    name, signal, allowed = "force_bias", "force", "offset in N, finite"
    study_case = StudyCase("bias", "the reading drops by 10 N for 2 s",
                           {"duration_s": 2.0, "magnitude": -10.0})

    def magnitude_ok(self, m):
        return math.isfinite(m)

    def corrupt(self, law):
        law.y = [v + if_then_else(law.on, law.fault.magnitude, 0.0) for v in law.u]


@register_fault_kind
class ForceGain(FaultKind):
    """A factor of magnitude on the reading (a gain change)."""
    name, signal, allowed = "force_gain", "force", "factor in [0, 100]"
    study_case = StudyCase("gain", "the sensor's gain halves for 2 s",
                           {"duration_s": 2.0, "magnitude": 0.5})

    def magnitude_ok(self, m):
        return 0 <= m <= 100

    def corrupt(self, law):
        law.y = [if_then_else(law.on, law.fault.magnitude * v, v) for v in law.u]


@register_fault_kind
class ForceSaturation(FaultKind):
    """The ADC clips the reading to +-magnitude (N)."""
    name, signal, allowed = "force_saturation", "force", "clip level in N, > 0"
    study_case = StudyCase("saturation", "the ADC clips at 15 N for 1 s",
                           {"duration_s": 1.0, "magnitude": 15.0})

    def magnitude_ok(self, m):
        return math.isfinite(m) and m > 0

    def corrupt(self, law):
        m = law.fault.magnitude
        law.y = [if_then_else(law.on, sym_min(sym_max(v, -m), m), v) for v in law.u]


@register_fault_kind
class EncoderMissedCounts(FaultKind):
    """The joint's encoder misses magnitude counts, evenly over the fault
    (the reading stays off by them afterwards)."""
    name, signal, allowed = "encoder_missed_counts", "encoders", "counts missed, finite, |.| <= 1e6"
    spreads = True
    study_case = StudyCase("missed_counts", "joint 1's encoder misses 200 counts over 1 s",
                           {"duration_s": 1.0, "magnitude": 200.0, "joint": 0})

    def magnitude_ok(self, m):
        return math.isfinite(m) and abs(m) <= 1e6

    def corrupt(self, law):
        f, t, t0 = law.fault, law.t, law.t0
        done = sym_min(sym_max((t - t0) / f.duration_s, 0.0), 1.0)
        # Counts missed so far; 0 before the start (t0 may be inf).
        missed = if_then_else(t >= t0 - TIME_TOLERANCE_S, floor(f.magnitude * done + 0.5), 0.0)
        law.y[f.joint] = law.u[f.joint] - missed * law.lsb


@register_fault_kind
class EncoderFrozen(_NoMagnitude):
    """The joint's reading stays at its last value (magnitude unused, 0)."""
    name, signal = "encoder_frozen", "encoders"
    study_case = StudyCase("encoder_frozen", "joint 2's reading freezes for 0.5 s",
                           {"duration_s": 0.5, "joint": 1})

    def corrupt(self, law):
        _hold(law, [law.fault.joint])


@register_fault_kind
class SurfaceRetreat(FaultKind):
    """The surface moves away from the arm by magnitude (m), back at the end."""
    name, signal = "surface_retreat", "surface"
    allowed = "displacement away from the arm in m, |.| <= 0.1"
    study_case = StudyCase("retreat", "the surface gives way by 5 mm for 0.5 s, then comes back",
                           {"duration_s": 0.5, "magnitude": 0.005})

    def magnitude_ok(self, m):
        return abs(m) <= 0.1

    def corrupt(self, law):
        # The wall sees the tip moved back by the retreat: x - shift.
        law.y[0] = law.u[0] - if_then_else(law.on, law.fault.magnitude, 0.0)


@register_fault_kind
class SurfaceMotion(FaultKind):
    """The surface moves along +x at magnitude (m/s) during the fault."""
    name, signal, allowed = "surface_motion", "surface", "speed along +x in m/s, |.| <= 1"
    study_case = StudyCase("surface_motion", "the surface moves away at 10 mm/s for 1 s",
                           {"duration_s": 1.0, "magnitude": 0.01})

    def magnitude_ok(self, m):
        return abs(m) <= 1

    def corrupt(self, law):
        f, t, t0 = law.fault, law.t, law.t0
        travelled = if_then_else(t >= t0 - TIME_TOLERANCE_S, sym_min(t - t0, f.duration_s), 0.0)
        law.y[0] = law.u[0] - f.magnitude * sym_max(travelled, 0.0)


@register_fault_kind
class StiffnessStep(FaultKind):
    """A factor of magnitude on K_e during the fault."""
    name, signal, allowed = "stiffness_step", "stiffness", "factor on K_e in (0, 100]"
    study_case = StudyCase("stiffness_step", "K_e doubles for 1 s",
                           {"duration_s": 1.0, "magnitude": 2.0})

    def magnitude_ok(self, m):
        return 0 < m <= 100

    def corrupt(self, law):
        u = law.u
        law.y = [if_then_else(law.on, law.fault.magnitude * u[0], u[0])]


@register_fault_kind
class StiffnessRamp(FaultKind):
    """K_e ramps to magnitude times its value over the fault and stays."""
    name, signal, allowed = "stiffness_ramp", "stiffness", "final factor on K_e in (0, 100]"
    spreads = True
    study_case = StudyCase("stiffness_ramp", "K_e ramps to 3 times over 2 s and stays",
                           {"duration_s": 2.0, "magnitude": 3.0})

    def magnitude_ok(self, m):
        return 0 < m <= 100

    def corrupt(self, law):
        f, t, t0 = law.fault, law.t, law.t0
        done = if_then_else(t >= t0 - TIME_TOLERANCE_S,
                            sym_min(sym_max((t - t0) / f.duration_s, 0.0), 1.0), 0.0)
        law.y = [law.u[0] * (1.0 + (f.magnitude - 1.0) * done)]


@register_fault_kind
class TorqueLimit(FaultKind):
    """The joint's torque limit drops to magnitude (N m)."""
    name, signal, allowed = "torque_limit", "drive", "torque limit in N m, >= 0"
    study_case = StudyCase("torque_limit", "joint 1's torque limit drops to 2 N m for 1 s",
                           {"duration_s": 1.0, "magnitude": 2.0, "joint": 0})

    def magnitude_ok(self, m):
        return math.isfinite(m) and m >= 0

    def corrupt(self, law):
        m, j, u = law.fault.magnitude, law.fault.joint, law.u
        law.y[j] = if_then_else(law.on, sym_min(sym_max(u[j], -m), m), u[j])


@register_fault_kind
class MotorScale(FaultKind):
    """A factor of magnitude on the joint's motor torque."""
    name, signal, allowed = "motor_scale", "drive", "factor on the motor torque in [-10, 10]"
    study_case = StudyCase("motor_scale", "joint 1's motor gives half its torque for 1 s",
                           {"duration_s": 1.0, "magnitude": 0.5, "joint": 0})

    def magnitude_ok(self, m):
        return -10 <= m <= 10

    def corrupt(self, law):
        m, j, u = law.fault.magnitude, law.fault.joint, law.u
        law.y[j] = if_then_else(law.on, m * u[j], u[j])
