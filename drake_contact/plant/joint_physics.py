"""Joint-side physics of the arm.

* Coulomb joint friction (the thesis, chapter 4: dry friction F_c sgn(qdot),
  viscous friction neglected), two models:

  - ``regularized``: tau_f = -sat(qdot F_c / v_s, -F_c, F_c), linear inside
    |qdot| < v_s (a MatrixGain and a Saturation: no Python). It cannot hold a
    static load: under any torque below F_c the joint creeps at
    v_s * torque / F_c until the torque is gone.
  - ``lugre`` (default): the LuGre bristle model (Canudas de Wit et al., 1995)
    without Stribeck effect, dz/dt = qdot - sigma0 |qdot| z / F_c,
    tau_f = -(sigma0 z + sigma1 dz/dt). It sticks: a load below F_c deflects the
    bristles by load / sigma0 (tens of micro-radians) and stops there, which is
    what leaves the force error of the thesis's hybrid-only runs (Fig 6.10).
    The bristle stiffness is set per joint from its inertia for a bristle
    frequency (50 Hz) the 1 ms plant step resolves, critically damped; z is
    advanced exactly for the velocity held over each step.
* Torque saturation at the controller's limits (Appendix E: 16, 2.5, 0.6 N m).
* Encoders: Drake's ``RotaryEncoders`` quantize the joint angles to the
  counts per revolution of chapter 3 (joint 1 614,400, joint 2 409,600,
  joint 3 2,000; Appendix B swaps the first two; we follow chapter 3). They
  are incremental, zeroed at power-up with the arm at q0, as the thesis's
  code reads them (q = q0 - counts / s): the counts quantize q - q0, so the
  reading at q0 is exact (quantizing from angle 0 would start joint 3 off by
  0.85 of its 3.1 mrad count).

Stability: the plant applies the friction torque explicitly over one step, so
the regularization acts as a viscous damper of F_c / v_s that must satisfy
F_c / v_s * h / M_ii < 2 (h the plant step, M_ii the joint's inertia).
:func:`check_friction_stability` refuses settings that break it.
"""

import dataclasses as dc

import numpy as np
import pydrake.symbolic as sym
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import AffineSystem, MatrixGain, Saturation
from pydrake.systems.sensors import RotaryEncoders

from drake_contact.arm_axis import LinearSystemBank, StackedSymbolicSystem
from drake_contact.blocks import AddSubdiagram, environment_configs
from drake_contact.errors import ScenarioError

#: Controller torque limits (N m) of Appendix E, joints 1-3.
THESIS_TORQUE_LIMITS = [16.0, 2.5, 0.6]

#: Encoder resolution (counts/rev) of chapter 3, joints 1-3.
THESIS_ENCODER_COUNTS = [614400, 409600, 2000]


FRICTION_MODELS = ("lugre", "regularized")


@dc.dataclass
class JointFrictionConfig:
    """Coulomb friction at the three joints (the plant's truth)."""

    # Include joint friction in the simulated plant.
    enabled: bool = True
    # lugre (sticks) or regularized (creeps).
    model: str = "lugre"
    # Coulomb level per joint (N m). Not measured in the thesis: Appendix B
    # gives the motors' *maximum* friction (4.41, 0.98 N m; joint 3 none) and
    # the code compensates 0.3 N m at joint 2. At the maxima, the thesis's own
    # gains would leave stiction dead bands of 3-5 mm in y and 20-35 mrad in
    # phi, and joint 2 could not push 20 N within its 2.5 N m limit (J^T f_d
    # alone takes 2.26 N m there). We take 1.0, 0.2 and 0.004 N m; joint 3's
    # stiction also damps the limit cycle its coarse encoder drives.
    levels: list[float] = dc.field(default_factory=lambda: [1.0, 0.2, 0.004])
    # Regularization velocity (rad/s) of the regularized model.
    regularization_velocity: float = 0.02
    # LuGre bristles: natural frequency (Hz) with the joint's inertia, and
    # damping ratio.
    bristle_frequency_hz: float = 50.0
    bristle_damping_ratio: float = 1.0

    def validate(self, prefix="joint_friction"):
        if self.model not in FRICTION_MODELS:
            raise ScenarioError(f"{prefix}.model = '{self.model}' is unknown: choose one of "
                                f"{', '.join(FRICTION_MODELS)}")
        if not (0.1 <= self.bristle_frequency_hz < 200):
            raise ScenarioError(f"{prefix}.bristle_frequency_hz = {self.bristle_frequency_hz} "
                                "is out of range: must be in [0.1, 200) Hz")
        if not (0 < self.bristle_damping_ratio <= 2):
            raise ScenarioError(f"{prefix}.bristle_damping_ratio = {self.bristle_damping_ratio} "
                                "is out of range: must be in (0, 2]")
        if len(self.levels) != 3 or any(not np.isfinite(x) or x < 0 for x in self.levels):
            raise ScenarioError(
                f"{prefix}.levels = {self.levels} is out of range: must be 3 values >= 0 N m")
        if not (self.regularization_velocity > 0):
            raise ScenarioError(
                f"{prefix}.regularization_velocity = {self.regularization_velocity} is out of "
                "range: must be > 0 rad/s")


@dc.dataclass
class EncoderConfig:
    """Quantization of the measured joint angles."""

    # Counts per revolution per joint; 0 disables quantization of that joint.
    counts_per_revolution: list[int] = dc.field(
        default_factory=lambda: list(THESIS_ENCODER_COUNTS))
    # Read a count at the middle of its interval, (n + 1/2) 2 pi / counts,
    # instead of its lower edge, n 2 pi / counts (false = the thesis). An
    # encoder's count is the angle rounded down, so its reading lies up to
    # one count below the angle, half a count on average; at the middle the
    # error is centred, within half a count either way (the midpoint
    # reconstruction of a truncating quantizer: Widrow & Kollar,
    # "Quantization Noise", 2008). Ours: joint 3's 2,000 counts are
    # 3.1 mrad, and phi held on the counts sat up to that far off.
    midpoint: bool = False

    def validate(self, prefix="encoders"):
        c = self.counts_per_revolution
        if len(c) != 3 or any(not 0 <= x <= 2**30 for x in c):
            raise ScenarioError(
                f"{prefix}.counts_per_revolution = {c} is out of range: must be 3 integers in "
                "[0, 2**30]")


def check_friction_stability(config: JointFrictionConfig, mass_matrix_diagonal, time_step):
    """Raises ScenarioError when the friction would be unstable at this plant
    step. Regularized: explicit damping F_c/v_s with h F_c/(v_s M_ii) >= 1
    (half the theoretical limit of 2, for margin). LuGre: the bristle
    frequency must be resolved, 2 pi f_b h < 1."""
    if not config.enabled:
        return
    if config.model == "lugre":
        if 2 * np.pi * config.bristle_frequency_hz * time_step >= 1.0:
            raise ScenarioError(
                f"joint_friction.bristle_frequency_hz = {config.bristle_frequency_hz} is out of "
                f"range at arm.time_step = {time_step}: must be < {1 / (2 * np.pi * time_step):.4g} Hz")
        return
    for i, (level, m_ii) in enumerate(zip(config.levels, mass_matrix_diagonal)):
        ratio = time_step * level / (config.regularization_velocity * m_ii)
        if ratio >= 1.0:
            v_min = time_step * level / m_ii
            raise ScenarioError(
                "joint_friction.regularization_velocity = "
                f"{config.regularization_velocity} is out of range at arm.time_step = "
                f"{time_step}: joint {i + 1} needs > {v_min:.3g} rad/s to stay stable")


class LuGreFriction(Diagram):
    """LuGre joint friction (no Stribeck, no viscous term), stepped at the
    plant's step.

    Input port: plant_state (6, [q; v]). Output port: torque (3, N m).
    State (discrete, 3): bristle deflections z (rad), one plant step ago.

    How it is computed: one ``SymbolicVectorSystem`` (``law``) that Drake
    evaluates in C++, with no Python per step: the torque, read by the plant
    every step, from [q; v] and z, and the exact bristle update every plant
    step. The torque's expressions do the former Python law's IEEE
    operations in its order; the update's exponential is C++'s std::exp,
    which differs from numpy's (an AVX-512 kernel on this machine) in the
    last bit on about 6 % of arguments (``tests/test_joint_physics.py``
    holds it to the numpy law within 1e-12).
    """

    def __init__(self, config, mass_matrix_diagonal, time_step):
        super().__init__()
        configs = environment_configs(config, JointFrictionConfig, "joint_friction")
        inertias = np.reshape(np.asarray(mass_matrix_diagonal, dtype=float), (len(configs), 3))
        h = float(time_step)
        pieces = [_lugre_expressions(c, m, h) for c, m in zip(configs, inertias)]
        builder = DiagramBuilder()
        law = builder.AddNamedSystem("law", StackedSymbolicSystem(pieces, time_period=h))
        builder.ExportInput(law.get_input_port(), "plant_state")
        builder.ExportOutput(law.get_output_port(), "torque")
        builder.BuildInto(self)


def _lugre_expressions(config: JointFrictionConfig, mass_matrix_diagonal, h):
    """One arm's LuGre law as :func:`StackedSymbolicSystem`'s piece: state
    z (3), input [q; v] (6), the update and the torque."""
    levels = np.asarray(config.levels if config.enabled else [0.0] * 3, dtype=float)
    w = 2 * np.pi * config.bristle_frequency_hz
    inertia = np.asarray(mass_matrix_diagonal, dtype=float)
    sigma0s = inertia * w**2
    sigma1s = 2 * config.bristle_damping_ratio * np.sqrt(sigma0s * inertia)
    state = np.array([sym.Variable(f"{kind}{i + 1}") for kind in ("q", "qdot")
                      for i in range(3)])
    z = np.array([sym.Variable(f"z{i + 1}") for i in range(3)])
    torque, update = [], []
    for i in range(3):
        level, sigma0, sigma1 = float(levels[i]), float(sigma0s[i]), float(sigma1s[i])
        qdot = state[3 + i]
        if level > 0:
            # tau = -(sigma0 z + sigma1 dz/dt), dz/dt = qdot - sigma0 |qdot| z / F_c.
            decay = _held(sigma0 * sym.abs(qdot) / level)
            rate = _held(qdot - decay * z[i])
            torque.append(-(sigma0 * z[i] + sigma1 * rate))
            # Exact for qdot held over the step: z relaxes to its sliding
            # value F_c sgn(qdot) / sigma0 at the rate sigma0 |qdot| / F_c;
            # a joint at rest keeps its z.
            z_slide = sym.if_then_else(qdot > 0, level * 1.0 / sigma0, level * -1.0 / sigma0)
            relax = sym.exp(_held(-(_held(sigma0 * sym.abs(qdot) / level)) * h))
            update.append(sym.if_then_else(
                qdot == 0.0, z[i], _held(z_slide + _held(_held(z[i] - z_slide) * relax))))
        else:
            torque.append(-(sigma0 * z[i] + sigma1 * 0.0))
            update.append(sym.Expression(0.0))
    # The state is z one step ago: the update stores z_n = update(z_(n-1),
    # qdot_n) from the plant's state at t_n, and the torque over the step
    # from t_n is the law at (z_n, qdot_n), z_n computed there by the same
    # expressions (the bristles advanced with the velocity they move at).
    update = [e if isinstance(e, sym.Expression) else sym.Expression(e) for e in update]
    advanced = dict(zip(z, update))
    torque = [e.Substitute(advanced) if isinstance(e, sym.Expression) else e for e in torque]
    return {"state": z, "input": state, "dynamics": update, "output": torque}


def _held(e):
    """``e``, evaluated to the same double, as an operand that Drake's
    simplifier will not merge into an enclosing sum or product."""
    return sym.max(e, -np.inf)


def AddJointFriction(builder: DiagramBuilder, config, *, mass_matrix_diagonal=None,
                     time_step=None, name="joint_friction"):
    """Adds the friction law; returns the added system (the
    :class:`LuGreFriction` or the regularized law's sub-diagram), named
    ``name``.

    Ports: ``plant_state`` (input, [q; v], 6) and ``torque`` (output, the
    friction torque, 3, N m, to add to the plant's applied generalized
    force). The LuGre model needs the joints' inertias (M's diagonal at q0)
    and the plant step. With a list of N configs (one model) and N inertia
    triples, the friction of N arms on the arm axis, each as alone.
    """
    configs = environment_configs(config, JointFrictionConfig, "joint_friction")
    models = {c.model for c in configs}
    if len(models) != 1:
        raise ScenarioError(f"joint_friction.model = {sorted(models)}: an ensemble's "
                            "environments share a structure")
    if configs[0].model == "lugre":
        return builder.AddNamedSystem(name, LuGreFriction(configs, mass_matrix_diagonal,
                                                          time_step))
    gains, limits = [], []
    for c in configs:
        levels = np.asarray(c.levels if c.enabled else [0.0] * 3, dtype=float)
        gain = np.zeros((3, 6))
        gain[:, 3:] = -np.diag(levels / c.regularization_velocity)
        gains.append(MatrixGain(gain))
        limits.append(levels)
    limits = np.concatenate(limits)

    def build(inner):
        slope = inner.AddNamedSystem(f"{name}_slope",
                                     gains[0] if len(gains) == 1 else LinearSystemBank(gains))
        clamp = inner.AddNamedSystem(f"{name}_clamp", Saturation(-limits, limits))
        inner.Connect(slope.get_output_port(), clamp.get_input_port())
        return {"plant_state": slope.get_input_port(), "torque": clamp.get_output_port()}
    return AddSubdiagram(builder, name, build)


def AddTorqueSaturation(builder: DiagramBuilder, limits, *, name="torque_saturation"):
    """Adds ``|tau_i| <= limits_i`` (N m); returns the Saturation system."""
    limits = np.asarray(limits, dtype=float)
    return builder.AddNamedSystem(name, Saturation(-limits, limits))


def encoder_reading(config: EncoderConfig, zero_positions):
    """What encoders zeroed at ``zero_positions`` (q0) read with the arm at
    q0 (rad): q0, half a count higher with ``config.midpoint``."""
    reading = np.asarray(zero_positions, dtype=float).copy()
    if config.midpoint:
        reading += [np.pi / c if c > 0 else 0.0 for c in config.counts_per_revolution]
    return reading


def AddEncoders(builder: DiagramBuilder, config, zero_positions, *, name="encoders"):
    """Adds incremental encoders zeroed at ``zero_positions`` (q0), reading
    q from the plant state [q; v] (6), as the sub-diagram ``name``; returns
    it. Ports: ``plant_state`` (input, 6) and ``joint_positions_measured``
    (output, 3, rad). With a list of N configs and N q0s, the encoders of N
    arms on the arm axis, each as alone.

    A joint with 0 counts per revolution is passed through unquantized
    (RotaryEncoders requires a positive count, so we use a huge one); with
    ``config.midpoint`` the others read half a count higher."""
    configs = environment_configs(config, EncoderConfig, "encoders")
    zeros = np.reshape(np.asarray(zero_positions, dtype=float), (len(configs), 3))
    counts = [int(c) if c > 0 else 2**30 for config in configs
              for c in config.counts_per_revolution]
    shifts = [AffineSystem(D=np.hstack([np.eye(3), np.zeros((3, 3))]), y0=-q0) for q0 in zeros]
    unshifts = [AffineSystem(D=np.eye(3), y0=encoder_reading(c, q0))
                for c, q0 in zip(configs, zeros)]

    def build(inner):
        shift = inner.AddNamedSystem(
            f"{name}_zero", shifts[0] if len(shifts) == 1 else LinearSystemBank(shifts))
        encoders = inner.AddNamedSystem(f"{name}_counts", RotaryEncoders(counts))
        unshift = inner.AddNamedSystem(
            f"{name}_angle", unshifts[0] if len(unshifts) == 1 else LinearSystemBank(unshifts))
        inner.Connect(shift.get_output_port(), encoders.get_input_port())
        inner.Connect(encoders.get_output_port(), unshift.get_input_port())
        return {"plant_state": shift.get_input_port(),
                "joint_positions_measured": unshift.get_output_port()}
    return AddSubdiagram(builder, name, build)
