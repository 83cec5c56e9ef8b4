"""Whether the force reading is plausible: the safety layer's flag that
holds the controller and its identifiers (``force_fault``).

A strain gauge read through a 16-bit ADC never gives the same number twice
in a row for long: its noise alone (+-2 N, mostly the 480 Hz ripple of the
D/A converters) moves it by 0.1-4 N from one 1 ms sample to the next, at
0.06 N a count. So, from the first contact on (the filtered force above
``contact_force_n`` once), the reading is flagged as implausible when

- it has not changed for ``sensor_frozen_samples`` samples in a row (a dead
  channel, a frozen DSP buffer, a clipping ADC), or
- it jumped by more than ``sensor_jump_n`` in one sample and the next
  sample repeats it exactly: a jump the noise cannot make, to a value that
  does not move, is a dropout, not a force (a real jump, a surface that
  gives way or a wall that hardens, is followed by noise and never
  flagged),

and stays flagged until the reading moves again, then ``sensor_settle_samples``
more: the 120 Hz filter the controllers read still carries the flagged
samples for a few milliseconds (its step response settles within 1 % in
6 ms).

The flag reads only the raw and filtered force, never the controller's
torque, so the controller and its identifiers can read it in the same
sample: :class:`drake_contact.control.hybrid_controller.HybridControlLaw`,
the neural compensator and the identifiers hold their state (their
integrals, estimates and weights) while it is up, and the supervisor holds
the arm (:mod:`drake_contact.control.safety_supervisor`).
"""

from pydrake.symbolic import Variable, if_then_else, logical_and, logical_or
from pydrake.symbolic import abs as sym_abs, max as sym_max
from pydrake.systems.primitives import SymbolicVectorSystem

from drake_contact.blocks import Layout
from drake_contact.plant.arm import CONTROL_PERIOD

# The monitor's state, updated every 1 ms.
_STATE = Layout(("raw_prev", 1), ("repeats", 1), ("armed", 1), ("jumped", 1), ("stuck", 1),
                ("settle", 1))


def ForceReadingMonitor(config) -> SymbolicVectorSystem:
    """The flag as a Drake ``SymbolicVectorSystem`` (no Python per step),
    updated every 1 ms, its output computed from the state and this
    sample's inputs.

    Input port (2): [the raw force (N, the ADC's reading), the filtered
    force (N: arms the check at the first contact)].
    Output port (2): [1.0 while the reading is flagged, else 0.0; 1.0
    while it is stuck (flagged, not counting the settle), else 0.0].
    State (6): :data:`_STATE`.

    ``config``: a :class:`drake_contact.control.safety_supervisor.SafetyConfig`
    (its ``sensor_*`` fields and ``contact_force_n``); ``sensor_frozen_samples``
    0 turns the check off (the output is 0)."""
    raw, force = Variable("force_raw"), Variable("force")
    state = [Variable(name) for name in _STATE.names()]
    raw_prev, repeats, armed, jumped, stuck, settle = state
    same = raw == raw_prev
    armed_now = if_then_else(force > config.contact_force_n, 1.0, armed)
    repeats_now = if_then_else(same, repeats + 1.0, 0.0)
    if config.sensor_frozen_samples == 0:
        stuck_now = 0.0 * raw
    else:
        # Stuck: repeated long enough, or repeating a jump, or still the
        # value that was flagged (armed by the first contact).
        repeated = logical_or(repeats_now >= config.sensor_frozen_samples,
                              logical_or(jumped > 0.5, stuck > 0.5))
        stuck_now = if_then_else(logical_and(same, logical_and(armed_now > 0.5, repeated)),
                                 1.0, 0.0)
    jumped_now = (0.0 * raw if config.sensor_jump_n == 0 else if_then_else(
        logical_and(raw != raw_prev, sym_abs(raw - raw_prev) > config.sensor_jump_n), 1.0, 0.0))
    # The sample the reading moves again is the settle's first.
    settle_now = if_then_else(stuck_now > 0.5, 0.0, if_then_else(
        stuck > 0.5, float(config.sensor_settle_samples), sym_max(settle - 1.0, 0.0)))
    flag = if_then_else(logical_or(stuck_now > 0.5, settle_now > 0.5), 1.0, 0.0)
    system = SymbolicVectorSystem(
        state=state, input=[raw, force], output=[flag, stuck_now], time_period=CONTROL_PERIOD,
        dynamics=[raw, repeats_now, armed_now, jumped_now, stuck_now, settle_now])
    system.set_name("force_monitor")
    return system
