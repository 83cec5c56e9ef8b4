"""Jacobian-transpose PI force control (Siciliano et al., Robotics:
Modelling, Planning and Control, 2009, sec. 9.4): the tip pushes along x with
f_c = f_d + K_P e + K_I sum(e) T - D_x xdot (e = f_d - f, summed only above
5 N) and holds y, phi by a PD, from start_s on (after the DSP's tare);
tau = J(q)^T [f_c, f_y, m_phi], every 1 ms."""
from pydrake.systems.framework import LeafSystem
from drake_contact.plant.planar_arm import tip_jacobian

DEFAULTS = dict(start_s=3.0, kp=0.2, ki=5.0, damping_x=60.0, stiffness_y=500.0, damping_y=10.0,
                stiffness_phi=10.0, damping_phi=0.2, contact_n=5.0, integral_limit_n=5.0)


class JacobianTransposePI(LeafSystem):
    """The torque is an output computed from the inputs at each 1 ms sample
    (as the DSP computed it and wrote the DAC in one interrupt); the update
    stores the integral the same evaluation used."""

    def __init__(self, gains):
        super().__init__()
        self.g = gains
        for name, size in (("tip_pose_measured", 3), ("tip_velocity_measured", 3),
                           ("joint_positions_estimated", 3), ("force_filtered", 1),
                           ("force_desired", 1)):
            self.DeclareVectorInputPort(name, size)
        self.DeclareDiscreteState(1)  # the integral of e (N s)
        self.DeclareVectorOutputPort("joint_torque_commanded", 3, self.torque)
        self.DeclarePeriodicDiscreteUpdateEvent(1e-3, 0.0, self.update)

    def integral(self, context):
        """The integral of e including this sample's error."""
        g = self.g
        f = self.GetInputPort("force_filtered").Eval(context)[0]
        f_d = self.GetInputPort("force_desired").Eval(context)[0]
        integral = context.get_discrete_state(0).GetAtIndex(0)
        if f > g["contact_n"]:
            integral = min(max(integral + (f_d - f) * 1e-3, -g["integral_limit_n"] / g["ki"]),
                           g["integral_limit_n"] / g["ki"])
        return integral

    def torque(self, context, output):
        if context.get_time() < self.g["start_s"]:
            output.SetFromVector([0.0, 0.0, 0.0])  # at rest while the DSP tares
            return
        g, port = self.g, lambda name: self.GetInputPort(name).Eval(context)
        (_, y, phi), (xd, yd, phid) = port("tip_pose_measured"), port("tip_velocity_measured")
        f, f_d = port("force_filtered")[0], port("force_desired")[0]
        integral = self.integral(context)
        wrench = [f_d + g["kp"] * (f_d - f) + g["ki"] * integral - g["damping_x"] * xd,
                  -g["stiffness_y"] * y - g["damping_y"] * yd,
                  -g["stiffness_phi"] * phi - g["damping_phi"] * phid]
        J = tip_jacobian(port("joint_positions_estimated"))
        output.SetFromVector([sum(J[i][j] * wrench[i] for i in range(3)) for j in range(3)])

    def update(self, context, discrete_state):
        if context.get_time() >= self.g["start_s"]:
            discrete_state.set_value(0, [self.integral(context)])


def make_controller(options):
    unknown = set(options) - set(DEFAULTS)
    if unknown:
        raise ValueError(f"unknown options {sorted(unknown)}: known are {sorted(DEFAULTS)}")
    return JacobianTransposePI(DEFAULTS | {k: float(v) for k, v in options.items()})
