"""What the thesis's DSP measures: the interface controllers and identifiers
are wired from.

:data:`MEASUREMENTS` is the one table of the measured signals: for each,
its size and meaning, the station block and output port that make it (the
kinematic estimator from the encoders, or the DSP's force input; never the
ground truth), the station signal (port and log key) it is exported as, and
whether controllers may read it. :class:`MeasuredSignals` holds their output
ports, one field each in the table's order;
:func:`drake_contact.diagram.MakeContactDiagram` fills it from the table,
exports and logs it, and hands it to the controller's and the identifiers'
wiring; :func:`drake_contact.plugins.controller_inputs` takes their sizes
and meanings from it. A new measured signal is one entry here (and its port
on the block that makes it).
"""

import dataclasses as dc

from pydrake.systems.framework import OutputPort


@dc.dataclass(frozen=True)
class Measurement:
    """One measured signal, all sampled every 1 ms.

    Frames: tip quantities are in the world frame of the arm's plane (x
    toward the wall, y along it, phi the tip's angle about z)."""

    size: int
    # What a controller or identifier reading it gets.
    meaning: str
    # The station block that makes it ("estimator" or "dsp") and its port there.
    source: str
    port: str
    # The station signal it is exported and logged as ("": not exported),
    # and that signal's meaning.
    signal: str = ""
    signal_meaning: str = ""
    # Controllers may read it (else identifiers only).
    controllers: bool = True


#: The measured signals, by the name controllers and identifiers read them
#: under (their input ports'), in MeasuredSignals' order.
MEASUREMENTS = {
    "tip_pose": Measurement(
        3, "estimated tip [x, y, phi] from the encoders (m, rad), world", "estimator",
        "tip_pose", "tip_pose_measured", "estimated tip [x, y, phi] from encoders (m, rad)"),
    "tip_velocity": Measurement(
        3, "35 Hz filtered tip velocity (m/s, rad/s)", "estimator", "tip_velocity",
        "tip_velocity_measured", "estimated tip velocity (m/s, rad/s)"),
    "tip_acceleration": Measurement(
        3, "35 Hz filtered tip acceleration (m/s^2, rad/s^2)", "estimator", "tip_acceleration",
        "tip_acceleration_measured", "estimated tip acceleration (m/s^2, rad/s^2)"),
    "joint_positions": Measurement(
        3, "joint angles q1, q2 as read, q3 filtered (rad)", "estimator", "joint_positions",
        "joint_positions_estimated", "q1, q2 as read, q3 filtered (rad)"),
    "joint_velocities": Measurement(
        3, "joint velocities by filtered backward differences (rad/s)", "estimator",
        "joint_velocities", "joint_velocities_estimated",
        "joint velocities by backward differences (rad/s)"),
    "force": Measurement(
        1, "normal force through the DSP's 120 Hz Butterworth (N, pushing > 0)", "dsp",
        "force_filtered", "force_filtered", "force_measured through the 120 Hz Butterworth (N)"),
    "force_raw": Measurement(
        1, "normal force as the DSP's ADC reads it, tared (N)", "dsp", "force_measured",
        "force_measured", "DSP force after ADC, scale, sign and tare (N)"),
    "tip_velocity_raw": Measurement(
        3, "tip velocity by unfiltered differences (m/s, rad/s)", "estimator",
        "tip_velocity_raw", controllers=False),
    "tip_acceleration_raw": Measurement(
        3, "tip acceleration by unfiltered differences", "estimator", "tip_acceleration_raw",
        controllers=False),
}


class MeasuredSignals:
    """Output ports of the measured signals: one attribute per entry of
    :data:`MEASUREMENTS` (``measured.force``, ...), and :meth:`items`."""

    def __init__(self, **ports: OutputPort):
        if set(ports) != set(MEASUREMENTS):
            raise ValueError(f"MeasuredSignals needs the ports {', '.join(MEASUREMENTS)}; "
                             f"got {', '.join(ports)}")
        self._ports = {name: ports[name] for name in MEASUREMENTS}

    def __getattr__(self, name):
        try:
            return self.__dict__["_ports"][name]
        except KeyError:
            raise AttributeError(name) from None

    def items(self):
        """(name, port) of every measured signal, in :data:`MEASUREMENTS`' order."""
        return self._ports.items()
