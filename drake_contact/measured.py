"""What the thesis's DSP measures: the interface controllers and identifiers
are wired from.

:class:`MeasuredSignals` holds the output ports of the kinematic estimator
(from the encoders) and of the DSP's force input, never the ground truth.
:func:`drake_contact.diagram.MakeContactDiagram` fills it and hands it to
the controller's and the identifiers' wiring; a new controller reads these
ports and nothing else from the plant.
"""

import dataclasses as dc

from pydrake.systems.framework import OutputPort


@dc.dataclass(frozen=True)
class MeasuredSignals:
    """Output ports of the measured signals, all sampled every 1 ms.

    Frames: tip quantities are in the world frame of the arm's plane (x
    toward the wall, y along it, phi the tip's angle about z)."""

    # Tip pose [x, y, phi] from the encoders through the forward kinematics (m, rad).
    tip_pose: OutputPort
    # Tip velocity, 35 Hz filtered differences of tip_pose (m/s, rad/s).
    tip_velocity: OutputPort
    # Tip acceleration, 35 Hz filtered second differences (m/s^2, rad/s^2).
    tip_acceleration: OutputPort
    # Joint angles q_hat: q1, q2 as read, q3 filtered (rad).
    joint_positions: OutputPort
    # Joint velocities by filtered backward differences (rad/s).
    joint_velocities: OutputPort
    # Normal force, tared, through the DSP's 120 Hz Butterworth (N, pushing > 0).
    force: OutputPort
    # Normal force as the DSP's ADC reads it, tared, unfiltered (N).
    force_raw: OutputPort
    # Tip velocity and acceleration by unfiltered differences (Fig 6.3).
    tip_velocity_raw: OutputPort
    tip_acceleration_raw: OutputPort

    def items(self):
        """(name, port) for every field, in declaration order."""
        return ((field.name, getattr(self, field.name)) for field in dc.fields(self))
