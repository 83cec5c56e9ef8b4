"""What the thesis's DSP measures: the interface controllers and identifiers
are wired from.

:data:`MEASUREMENTS` is the one table of the measured signals. A signal's
name there is the station's output port, its log key and the input port a
controller declares to read it (``force_filtered``, ``tip_pose_measured``,
...); the table also gives its size and meaning, the station block and port
that make it (the kinematic estimator from the encoders, or the DSP's force
input; never the ground truth), and its *role*, the shorter input name the
station's own systems and identifiers use (``force``, ``tip_pose``, ...).
:class:`MeasuredSignals` holds their output ports;
:func:`drake_contact.diagram.MakeContactDiagram` fills it from the table,
exports and logs it, and wires it; :func:`drake_contact.plugins.controller_inputs`
takes the sizes and meanings from it. A new measured signal is one entry here
(and its port on the block that makes it).
"""

import dataclasses as dc

from pydrake.systems.framework import OutputPort


@dc.dataclass(frozen=True)
class Measurement:
    """One measured signal, sampled every 1 ms. Its name (the key of
    :data:`MEASUREMENTS`) is the station's output port, its log key and the
    input port a controller declares to read it.

    Frames: tip quantities are in the world frame of the arm's plane (x
    toward the wall, y along it, phi the tip's angle about z)."""

    size: int
    meaning: str
    # The station block that makes it ("estimator" or "dsp") and its port there.
    source: str
    port: str
    # The input port name of the station's own systems and of identifiers
    # (the thesis's laws read "force", "tip_pose", ...; an identifier's
    # ``signals`` option chooses which measured signal feeds "force",
    # "tip_pose", "tip_velocity" and "tip_acceleration").
    role: str
    # Exported and logged by the station, and readable by controllers
    # (else identifiers only).
    station: bool = True


#: The measured signals by name, in MeasuredSignals' order.
MEASUREMENTS = {
    "tip_pose_measured": Measurement(
        3, "estimated tip [x, y, phi] from the encoders (m, rad), world", "estimator",
        "tip_pose", "tip_pose"),
    "tip_velocity_measured": Measurement(
        3, "estimated tip velocity, 35 Hz filtered differences (m/s, rad/s)", "estimator",
        "tip_velocity", "tip_velocity"),
    "tip_acceleration_measured": Measurement(
        3, "estimated tip acceleration, 35 Hz filtered differences (m/s^2, rad/s^2)",
        "estimator", "tip_acceleration", "tip_acceleration"),
    "joint_positions_estimated": Measurement(
        3, "joint angles q1, q2 as read, q3 filtered (rad)", "estimator", "joint_positions",
        "joint_positions"),
    "joint_velocities_estimated": Measurement(
        3, "joint velocities by filtered backward differences (rad/s)", "estimator",
        "joint_velocities", "joint_velocities"),
    "force_filtered": Measurement(
        1, "normal force through the DSP's 120 Hz Butterworth (N, pushing > 0)", "dsp",
        "force_filtered", "force"),
    "force_measured": Measurement(
        1, "normal force as the DSP's ADC reads it: scaled, sign, tared (N)", "dsp",
        "force_measured", "force_raw"),
    "tip_velocity_raw": Measurement(
        3, "tip velocity by unfiltered differences (m/s, rad/s)", "estimator",
        "tip_velocity_raw", "tip_velocity_raw", station=False),
    "tip_acceleration_raw": Measurement(
        3, "tip acceleration by unfiltered differences", "estimator", "tip_acceleration_raw",
        "tip_acceleration_raw", station=False),
}


def by_role() -> dict:
    """{role: name} of every measured signal."""
    return {m.role: name for name, m in MEASUREMENTS.items()}


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
