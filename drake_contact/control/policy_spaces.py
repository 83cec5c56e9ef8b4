"""What a learned policy sees and what it commands, shared by the policy
controller (:mod:`drake_contact.control.policy`, which runs a policy in a
scenario and in the benchmark) and the Gymnasium environment
(:mod:`drake_contact.gym`), so the two cannot differ.

**Action** (4 numbers, each in [-1, 1]; values outside are clipped there),
acting on the hybrid law (thesis 4.13-4.15) in contact only, so that the
zero action is the law unmodified, bit for bit:

=====  ====================  ==============================================
index  name                  effect on the hybrid law in contact
=====  ====================  ==============================================
0      force_residual        adds 5 a N to the force command along x
                             (J^T S r: a residual on the law's force)
1      force_gain_scale      K_fp times 4^a (0.25-4 times)
2      integral_gain_scale   K_fi times 4^a (0.25-4 times)
3      damping_x             D_x + 100 a N s/m, at least 0 (active
                             damping along x, Volpe & Khosla 1993)
=====  ====================  ==============================================

Scaling gains per step is variable-impedance control (e.g. Martin-Martin
et al. 2019, "Variable impedance control in end-effector space", IROS);
adding to a fixed law's command is residual learning (Johannink et al. 2019,
"Residual reinforcement learning for robot control", ICRA). In the approach
the action has no effect: the law approaches as the thesis's does.

**Observation** (:data:`OBSERVATION`, 10 numbers, each a measured signal
over a scale that makes it of order one; no ground truth): the force error
and its mean magnitude over the last control period, the force and f_d, the
force's rate, the tip's x velocity, y and phi errors, whether the law is in
contact (its mode at the previous 1 ms sample) and the time since the first
contact; each clipped to [-100, 100] (:data:`OBSERVATION_BOUND`).
"""

import numpy as np

from drake_contact.arm_axis import SCALAR_OPS
from drake_contact.blocks import Layout

#: The action's fields, in order.
ACTION = Layout(("force_residual", 1), ("force_gain_scale", 1), ("integral_gain_scale", 1),
                ("damping_x", 1))
#: Action bounds (each field): outside, clipped.
ACTION_LOW, ACTION_HIGH = -1.0, 1.0
#: Newtons of force residual per unit of action.
RESIDUAL_N = 5.0
#: A gain's scale is GAIN_SCALE_BASE ** a (a in [-1, 1]).
GAIN_SCALE_BASE = 4.0
#: N s/m of x damping added per unit of action.
DAMPING_N_S_PER_M = 100.0

#: The observation's fields: (name, scale, meaning); the observation is
#: each signal divided by its scale.
OBSERVATION_FIELDS = (
    ("force_error", 10.0, "f_d - f, the DSP's filtered force f (N)"),
    ("mean_abs_force_error", 10.0,
     "mean |f_d - f| over the 1 ms samples of the last control period (N)"),
    ("force", 20.0, "f (N)"),
    ("force_desired", 20.0, "f_d (N)"),
    ("force_rate", 1000.0, "(f_k - f_(k-1)) / 1 ms (N/s)"),
    ("tip_velocity_x", 0.01, "the estimator's xdot (m/s)"),
    ("y_error", 0.001, "y - y_d, the estimator's y (m)"),
    ("phi_error", 0.01, "phi - phi_d (rad)"),
    ("in_contact", 1.0, "1 if the law was in contact at the previous sample, else 0"),
    ("time_in_contact", 10.0, "time since the first switch to contact, 0 before (s)"),
)
OBSERVATION = Layout(*((name, 1) for name, _, _ in OBSERVATION_FIELDS))
#: Each observation is clipped to [-OBSERVATION_BOUND, OBSERVATION_BOUND]
#: (an impact's force rate, a lost wall).
OBSERVATION_BOUND = 100.0
_SCALES = [scale for _, scale, _ in OBSERVATION_FIELDS]


def check_action(action, where="action") -> np.ndarray:
    """``action`` as a float64 vector of ACTION.size; ValueError in one line
    for a wrong shape or a non-finite entry."""
    try:
        a = np.asarray(action, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{where} = {action!r} is not {ACTION.size} numbers") from None
    if a.shape != (ACTION.size,):
        raise ValueError(f"{where} has shape {a.shape}: must be ({ACTION.size},) "
                         f"[{', '.join(ACTION.names())}]")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{where} = {a.tolist()} is not finite: each entry must be a number "
                         f"in [{ACTION_LOW:g}, {ACTION_HIGH:g}]")
    return a


def apply_action(action, force_gain, integral_gain, damping_x, ops=SCALAR_OPS):
    """The hybrid law's (residual force (N), K_fp, K_fi, D_x) under
    ``action`` (clipped to its bounds). The zero action returns the gains
    unchanged and a residual of 0. One environment: ``action`` (4,) and
    the gains floats; N (``ops`` ARRAY_OPS, see
    :func:`drake_contact.arm_axis.arm_axis_ops`): ``action`` (N x 4) and
    the gains arrays (N,), each environment bit for bit its values alone."""
    columns = action.tolist() if ops is SCALAR_OPS else np.asarray(action, dtype=float).T
    a0, a1, a2, a3 = (ops.clip(v, ACTION_LOW, ACTION_HIGH) for v in columns)
    return (RESIDUAL_N * a0, force_gain * ops.pow(GAIN_SCALE_BASE, a1),
            integral_gain * ops.pow(GAIN_SCALE_BASE, a2),
            ops.maximum(damping_x + DAMPING_N_S_PER_M * a3, 0.0))


def observation(force_desired, force, force_previous, mean_abs_error, velocity_x, y_error,
                phi_error, in_contact, time_in_contact, ops=SCALAR_OPS) -> list:
    """The observation (a list of OBSERVATION.size values) from the
    measured values, each over its scale: Python floats for one
    environment, arrays (N,) for N (``ops`` ARRAY_OPS), each environment's
    bit for bit its values alone."""
    raw = (force_desired - force, mean_abs_error, force, force_desired,
           (force - force_previous) / 1e-3, velocity_x, y_error, phi_error, in_contact,
           time_in_contact)
    return [ops.clip(v / s, -OBSERVATION_BOUND, OBSERVATION_BOUND) for v, s in zip(raw, _SCALES)]
