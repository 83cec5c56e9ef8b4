"""Closed-form kinematics and dynamics of the 3-DOF planar arm (thesis
Appendix C-D), for the hot path: one evaluation is a few dozen scalar
operations instead of several MultibodyPlant calls.

Every function takes the trigonometric functions it should use (``math``'s
for Python floats, numpy's for arrays over an ensemble's environments,
``pydrake.symbolic``'s for Expressions), so the same formulas serve the
controller's model (Python scalars, or arrays elementwise with link
parameters per environment, one callback) and the simulator's tip
kinematics and the estimator's forward kinematics (``SymbolicVectorSystem``s,
evaluated in C++ with no Python per step).

Conventions (thesis Appendices A-C): q = (theta_1, theta_2, theta_3),
joints about z in the horizontal plane (gravity gives no joint torque);
link i has length a_i, mass m_i, its COM at L_i = a_i + S_ix from joint i,
and Izz_i about its COM. The tip is at the end of link 3 and phi = q1 + q2
+ q3. ``tests/test_planar_arm.py`` checks every function against Drake's
``MultibodyPlant`` of the URDF (to 1e-12) and against the thesis's own
closed forms (``tests/thesis_closed_forms.py``).
"""

import dataclasses as dc
import math

from drake_contact.plant.arm import LINK_COM_OFFSETS, LINK_IZZ, LINK_LENGTHS, LINK_MASSES


@dc.dataclass(frozen=True)
class ArmParameters:
    """Link data of the arm (SI units); defaults: the URDF's."""

    lengths: tuple = LINK_LENGTHS
    masses: tuple = LINK_MASSES
    com_offsets: tuple = LINK_COM_OFFSETS
    izz: tuple = LINK_IZZ

    def scaled(self, mass_scale, inertia_scale) -> "ArmParameters":
        """Masses and COM inertias multiplied per link (a controller's
        belief about the arm); lengths and COM positions unchanged."""
        return dc.replace(
            self, masses=tuple(m * s for m, s in zip(self.masses, mass_scale)),
            izz=tuple(i * s for i, s in zip(self.izz, inertia_scale)))


def tip_pose(q, arm: ArmParameters = ArmParameters(), sin=math.sin, cos=math.cos):
    """[x, y, phi] (m, m, rad) of the tip (Appendix C1)."""
    a1, a2, a3 = arm.lengths
    q12 = q[0] + q[1]
    q123 = q12 + q[2]
    return [a1 * cos(q[0]) + a2 * cos(q12) + a3 * cos(q123),
            a1 * sin(q[0]) + a2 * sin(q12) + a3 * sin(q123),
            q123]


def tip_jacobian(q, arm: ArmParameters = ArmParameters(), sin=math.sin, cos=math.cos):
    """J = d[x, y, phi]/dq as three rows (Appendix C2, eq. 2-1)."""
    a1, a2, a3 = arm.lengths
    q12 = q[0] + q[1]
    q123 = q12 + q[2]
    s3, s2, s1 = a3 * sin(q123), a2 * sin(q12), a1 * sin(q[0])
    c3, c2, c1 = a3 * cos(q123), a2 * cos(q12), a1 * cos(q[0])
    return [[-s3 - s2 - s1, -s3 - s2, -s3],
            [c3 + c2 + c1, c3 + c2, c3],
            [1.0, 1.0, 1.0]]


def jdot_qdot(q, qdot, arm: ArmParameters = ArmParameters(), sin=math.sin, cos=math.cos):
    """dJ/dt qdot (Appendix C2, eq. 2-3 with the rates the print lost):
    -[sum a_i C_(1..i) w_(1..i)^2, sum a_i S_(1..i) w_(1..i)^2, 0]."""
    a1, a2, a3 = arm.lengths
    q12 = q[0] + q[1]
    q123 = q12 + q[2]
    w1 = qdot[0]
    w12 = w1 + qdot[1]
    w123 = w12 + qdot[2]
    k1, k2, k3 = a1 * w1 * w1, a2 * w12 * w12, a3 * w123 * w123
    return [-(k1 * cos(q[0]) + k2 * cos(q12) + k3 * cos(q123)),
            -(k1 * sin(q[0]) + k2 * sin(q12) + k3 * sin(q123)),
            0.0]


def mass_matrix_and_bias(q, qdot, arm: ArmParameters = ArmParameters(), sin=math.sin,
                         cos=math.cos):
    """(M(q) as three rows, h(q, qdot)): tau = M qddot + h, with h the
    Coriolis and centrifugal torques (Appendix D, collected as Appendix E's
    M[][] and OMG[] with the repairs documented in thesis_closed_forms)."""
    a1, a2, _ = arm.lengths
    m1, m2, m3 = arm.masses
    I1, I2, I3 = arm.izz
    L1, L2, L3 = (a + s for a, s in zip(arm.lengths, arm.com_offsets))
    s2, c2 = sin(q[1]), cos(q[1])
    s3, c3 = sin(q[2]), cos(q[2])
    q23 = q[1] + q[2]
    s23, c23 = sin(q23), cos(q23)
    ta = a2 * c3 + a1 * c23 + L3        # joint 1 -> COM 3, frame 3 x
    tb = a2 * s3 + a1 * s23             # and -y
    tc = a2 + a1 * c2 + arm.com_offsets[1]  # joint 1 -> COM 2, frame 2 x
    r23 = a2 * c3 + L3                  # joint 2 -> COM 3, frame 3 x
    M11 = I1 + I2 + I3 + m3 * (ta * ta + tb * tb) + m2 * (tc * tc + a1 * a1 * s2 * s2) \
        + m1 * L1 * L1
    M12 = I2 + I3 + m3 * (ta * r23 + a2 * s3 * tb) + m2 * L2 * tc
    M13 = I3 + m3 * L3 * ta
    M22 = I2 + I3 + m3 * (r23 * r23 + a2 * a2 * s3 * s3) + m2 * L2 * L2
    M23 = I3 + m3 * L3 * r23
    M33 = I3 + m3 * L3 * L3
    w1 = qdot[0]
    w12 = w1 + qdot[1]
    w123 = w12 + qdot[2]
    w1s, w12s, w123s = w1 * w1, w12 * w12, w123 * w123
    h1 = ((m3 * a1 * (s23 * ta - c23 * tb) + m2 * a1 * s2 * (tc - a1 * c2)) * w1s
          + (m3 * a2 * (s3 * ta - c3 * tb) - m2 * a1 * s2 * L2) * w12s
          - m3 * L3 * tb * w123s)
    h2 = ((m3 * a1 * (s23 * r23 - a2 * s3 * c23) + m2 * a1 * s2 * L2) * w1s
          + m3 * a2 * s3 * (r23 - a2 * c3) * w12s
          - m3 * a2 * s3 * L3 * w123s)
    h3 = m3 * L3 * (a1 * s23 * w1s + a2 * s3 * w12s)
    return [[M11, M12, M13], [M12, M22, M23], [M13, M23, M33]], [h1, h2, h3]


def solve3(A, b):
    """x with A x = b for a 3 x 3 A (rows) by Cramer's rule, in scalars
    (numpy's solve costs more per call than the arithmetic here), or
    elementwise on arrays (one system per environment)."""
    (a, b_, c), (d, e, f), (g, h, i) = A
    co0, co1, co2 = e * i - f * h, f * g - d * i, d * h - e * g
    det = a * co0 + b_ * co1 + c * co2
    r0, r1, r2 = b
    return [(r0 * co0 + b_ * (r2 * f - r1 * i) + c * (r1 * h - r2 * e)) / det,
            (a * (r1 * i - r2 * f) + r0 * co1 + c * (r2 * d - r1 * g)) / det,
            (a * (r2 * e - r1 * h) + b_ * (r1 * g - r2 * d) + r0 * co2) / det]
