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

from pydrake.systems.framework import LeafSystem

from drake_contact.blocks import Layout
from drake_contact.plant.arm import DeclareSampledUpdate, is_sample_time

# The monitor's output and held state: [flag, then memory].
_STATE = Layout(("flag", 1), ("raw_prev", 1), ("repeats", 1), ("armed", 1),
                ("jumped", 1), ("stuck", 1), ("settle", 1))
#: The monitor output's parts: the flag, the memory (a Demultiplexer's sizes).
MONITOR_SIZES = [1, _STATE.size - 1]


class ForceReadingMonitor(LeafSystem):
    """The flag as one leaf, evaluated at each 1 ms sample from the inputs
    and held between samples (as the supervisor's law).

    Input ports: ``force_raw`` (1, N, the ADC's reading), ``force`` (1, N,
    filtered: arms the check at the first contact).
    Output port: ``monitor`` (7): the flag (1.0 while the reading is
    flagged, else 0.0), then the memory (:data:`MONITOR_SIZES`).

    ``config``: a :class:`drake_contact.control.safety_supervisor.SafetyConfig`
    (its ``sensor_*`` fields and ``contact_force_n``); ``sensor_frozen_samples``
    0 turns the check off."""

    def __init__(self, config):
        super().__init__()
        self._frozen = config.sensor_frozen_samples
        self._jump = config.sensor_jump_n
        self._settle = config.sensor_settle_samples
        self._contact = config.contact_force_n
        self._raw = self.DeclareVectorInputPort("force_raw", 1)
        self._force = self.DeclareVectorInputPort("force", 1)
        held = [0.0] * _STATE.size
        held[_STATE.raw_prev] = float("nan")
        self._held = self.DeclareDiscreteState(held)
        self._out = self.DeclareVectorOutputPort(
            "monitor", _STATE.size, self._calc,
            prerequisites_of_calc={self._raw.ticket(), self._force.ticket(), self.xd_ticket(),
                                   self.time_ticket()})
        DeclareSampledUpdate(self, lambda context, state: state.set_value(
            self._out.Eval(context)))

    def _calc(self, context, output):
        held = context.get_discrete_state(self._held).value()
        if not is_sample_time(context.get_time()) or self._frozen == 0:
            output.SetFromVector(held)
            return
        _, raw_prev, repeats, armed, jumped, stuck, settle = held.tolist()
        raw = float(self._raw.Eval(context)[0])
        armed = armed or float(self._force.Eval(context)[0]) > self._contact
        was_stuck = stuck
        if raw == raw_prev:
            repeats += 1
            # Stuck: repeated long enough, or repeating a jump, or still
            # the value that was flagged.
            stuck = armed and (repeats >= self._frozen or jumped or stuck)
            jumped = False
        else:
            repeats = 0
            stuck = False
            jumped = self._jump > 0 and abs(raw - raw_prev) > self._jump
        if stuck:
            settle = 0
        elif was_stuck:
            settle = self._settle  # the sample the reading moves again is the first
        else:
            settle = max(settle - 1, 0)
        flag = stuck or settle > 0
        output.SetFromVector([float(flag), raw, repeats, float(armed), float(jumped),
                              float(stuck), float(settle)])
