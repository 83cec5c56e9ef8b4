"""The compliant wall alone, driven by a point mass stepped like the plant
(symplectic Euler, force held over the step) or by a prescribed motion."""

import dataclasses as dc

import numpy as np
import pytest

from drake_contact.plant.compliant_wall import CompliantWall, EnvironmentConfig
from drake_contact.errors import ScenarioError

H = 1e-3
SURFACE = 0.456


def make_wall(**fields):
    config = dc.replace(EnvironmentConfig(surface_x=SURFACE), **fields)
    wall = CompliantWall(config, H)
    return wall, wall.CreateDefaultContext()


def eval_outputs(wall, context):
    return {name: wall.GetOutputPort(name).Eval(context).copy()
            for name in ("force_on_tip", "contact_force", "penetration", "true_impedance")}


def step_wall(wall, context, n):
    new_state = wall.EvalUniquePeriodicDiscreteUpdate(context).get_vector().value().copy()
    context.SetDiscreteState(new_state)
    context.SetTime((n + 1) * H)


def push_point_mass(wall, context, *, mass, push, x0, v0, steps, drag=0.0):
    """A point mass on the tip, pushed along +x by ``push`` N, with a viscous
    ``drag`` (N s/m) standing for the controller's damping."""
    x, v = x0, v0
    rows = []
    for n in range(steps):
        wall.GetInputPort("tip_state").FixValue(context, [x, 0, 0, v, 0, 0])
        out = eval_outputs(wall, context)
        rows.append((n * H, x, v, out["contact_force"][0], out["penetration"][0]))
        step_wall(wall, context, n)
        v += H * (push + out["force_on_tip"][0] - drag * v) / mass
        x += H * v
    return np.array(rows)


@pytest.mark.parametrize("stiffness", [7e3, 6.2e4])
def test_static_penetration_is_force_over_stiffness(stiffness):
    wall, context = make_wall(stiffness=stiffness, damping=30.0, mass=0.02)
    rows = push_point_mass(wall, context, mass=6.8, push=20.0, x0=SURFACE - 1e-3,
                           v0=0.0, steps=4000, drag=50.0)
    _, x, v, f, xe = rows[-1]
    assert abs(v) < 1e-6
    assert xe == pytest.approx(20.0 / stiffness, rel=1e-4)
    assert f == pytest.approx(20.0, rel=1e-4)
    assert x - SURFACE == pytest.approx(xe)


def test_hunt_crossley_static_penetration():
    n, x_ref, K = 1.5, 1e-3, 7e3
    wall, context = make_wall(stiffness=K, damping=30.0, law="hunt_crossley",
                              hunt_crossley_exponent=n,
                              hunt_crossley_reference_penetration=x_ref)
    rows = push_point_mass(wall, context, mass=6.8, push=20.0, x0=SURFACE - 1e-3,
                           v0=0.0, steps=4000, drag=50.0)
    expected = (20.0 * x_ref ** (n - 1) / K) ** (1 / n)
    assert rows[-1, 4] == pytest.approx(expected, rel=1e-4)


def test_never_pulls_and_a_fast_retreat_leaves_the_surface():
    # Heavy damping: the linear law K x + B v goes negative when the tip
    # retreats; the wall must give zero, not a pull.
    wall, context = make_wall(stiffness=7e3, damping=400.0, mass=0.05)
    forces, touching = [], []
    for n in range(400):
        t = n * H
        # In 3 mm over 0.1 s, then out at 0.3 m/s.
        x = SURFACE + (0.003 * t / 0.1 if t < 0.1 else 0.003 - 0.3 * (t - 0.1))
        v = 0.03 if t < 0.1 else -0.3
        wall.GetInputPort("tip_state").FixValue(context, [x, 0, 0, v, 0, 0])
        out = eval_outputs(wall, context)
        forces.append(out["contact_force"][0])
        touching.append(out["penetration"][0] > 0)
        assert out["force_on_tip"][0] == -out["contact_force"][0]
        step_wall(wall, context, n)
    forces = np.array(forces)
    assert forces.min() >= 0.0
    assert forces[:100].max() > 10.0
    # Right after the reversal the tip outruns the surface: no contact.
    assert not any(touching[102:110])
    assert forces[102:].max() == 0.0


@pytest.mark.parametrize("damping,mass", [(0.0, 0.0), (0.0, 0.05), (30.0, 0.0), (30.0, 0.1)])
def test_bounce_leaves_with_no_more_energy_than_it_arrived_with(damping, mass):
    wall, context = make_wall(stiffness=6.2e4, damping=damping, mass=mass)
    m, v_in = 6.8, 0.1
    rows = push_point_mass(wall, context, mass=m, push=0.0, x0=SURFACE - 1e-3,
                           v0=v_in, steps=600)
    v_out = rows[-1, 2]
    assert v_out < 0, "the mass must bounce back"
    assert rows[-1, 3] == 0.0 and rows[-1, 1] < SURFACE
    ke_in, ke_out = 0.5 * m * v_in**2, 0.5 * m * v_out**2
    if damping == 0.0:
        # A lossless spring: the symplectic step keeps the energy to within
        # the discrete timing of contact onset and release (0.1 % here).
        assert ke_out == pytest.approx(ke_in, rel=0.01)
    else:
        assert ke_out < 0.9 * ke_in


@pytest.mark.parametrize("stiffness", [1e3, 1e6])
@pytest.mark.parametrize("mass", [0.0, 0.1])
@pytest.mark.parametrize("damping", [0.0, 50.0])
def test_stable_at_parameter_extremes(stiffness, mass, damping):
    wall, context = make_wall(stiffness=stiffness, damping=damping, mass=mass)
    # 6.8 kg is the arm's effective mass along x near q0; 50 N s/m of
    # damping on the mass stands for the controller's.
    x, v = SURFACE - 1e-3, 0.05
    for n in range(3000):
        wall.GetInputPort("tip_state").FixValue(context, [x, 0, 0, v, 0, 0])
        f = wall.GetOutputPort("force_on_tip").Eval(context)[0]
        step_wall(wall, context, n)
        v += H * (20.0 + f - 50.0 * v) / 6.8
        x += H * v
        assert np.isfinite(x) and abs(f) < 1e4
    assert x - SURFACE == pytest.approx(20.0 / stiffness, rel=1e-3)


def test_free_surface_relaxes_back_after_release():
    wall, context = make_wall(stiffness=7e3, damping=20.0, mass=0.05)
    for n in range(50):
        wall.GetInputPort("tip_state").FixValue(context, [SURFACE + 2e-3, 0, 0, 0, 0, 0])
        step_wall(wall, context, n)
    wall.GetInputPort("tip_state").FixValue(context, [SURFACE - 0.01, 0, 0, 0, 0, 0])
    for n in range(50, 1050):
        step_wall(wall, context, n)
    s, sd = context.get_discrete_state_vector().value()[:2]
    assert abs(s) < 1e-6 and abs(sd) < 1e-4


def test_tangential_friction_opposes_sliding_and_sticks_when_slow():
    wall, context = make_wall(stiffness=7e3, damping=0.0, mass=0.0,
                              friction_coefficient=0.5, stiction_velocity=0.01)
    port = wall.GetInputPort("tip_state")
    port.FixValue(context, [SURFACE + 1e-3, 0, 0, 0, 0.05, 0])
    fx, fy, _ = wall.GetOutputPort("force_on_tip").Eval(context)
    assert fx == pytest.approx(-7.0) and fy == pytest.approx(-0.5 * 7.0)
    port.FixValue(context, [SURFACE + 1e-3, 0, 0, 0, -0.002, 0])
    fy = wall.GetOutputPort("force_on_tip").Eval(context)[1]
    assert fy == pytest.approx(0.5 * 7.0 * 0.2)
    port.FixValue(context, [SURFACE - 1e-3, 0, 0, 0, 0.05, 0])
    np.testing.assert_array_equal(wall.GetOutputPort("force_on_tip").Eval(context), 0.0)


def test_stiffness_drift_and_true_impedance_output():
    wall, context = make_wall(stiffness=1e4, damping=5.0, mass=0.1,
                              stiffness_drift_per_s=0.02)
    wall.GetInputPort("tip_state").FixValue(context, [SURFACE + 1e-3, 0, 0, 0, 0, 0])
    for n in range(10000):  # K_e is state: step it to t = 10 s
        step_wall(wall, context, n)
    assert context.get_time() == pytest.approx(10.0)
    np.testing.assert_allclose(
        wall.GetOutputPort("true_impedance").Eval(context), [0.1, 5.0, 1.2e4])
    assert wall.GetOutputPort("contact_force").Eval(context)[0] == pytest.approx(12.0)


@pytest.mark.parametrize("field,value,words", [
    ("stiffness", 0.0, "environment.stiffness = 0.0 is out of range: must be > 0 N/m"),
    ("stiffness", -5.0, "environment.stiffness = -5.0"),
    ("damping", -1.0, "must be >= 0 N s/m"),
    ("mass", -0.1, "must be >= 0 kg"),
    ("law", "hertz", "choose one of linear, hunt_crossley"),
    ("acceleration_smoothing", 1.0, "must be in [0, 1)"),
])
def test_bad_parameters_name_the_field_and_range(field, value, words):
    with pytest.raises(ScenarioError, match=words.replace("(", r"\(").replace(")", r"\)")
                       .replace("[", r"\[").replace("]", r"\]")):
        make_wall(**{field: value})


def test_no_python_runs_in_the_wall():
    from drake_contact.diagram import leaf_systems
    wall, _ = make_wall()
    systems = list(leaf_systems(wall))
    assert [s.get_name() for s in systems] == ["contact_law", "outputs"]
    for system in systems:
        assert type(system).__module__.startswith("pydrake"), system.get_name()


def reference_wall_step(c, tip, state, t, h):
    """The wall as the former Python LeafSystem computed it (numpy scalars,
    K_e as the fifth state): returns (outputs [force_on_tip, contact_force,
    penetration, true_impedance] as 8 values, next state with K_e(t))."""
    x, _, _, vx, vy, _ = tip
    s, sd, acc, v_prev, K = state
    xe = x - c.surface_x
    touching = xe > 0.0 and xe >= s
    fn = 0.0
    if touching:
        elastic = K * xe + c.damping * vx
        if c.law == "hunt_crossley":
            elastic *= (xe / c.hunt_crossley_reference_penetration) ** (
                c.hunt_crossley_exponent - 1.0)
        fn = max(elastic + c.mass * acc, 0.0)
    ft = 0.0
    if fn > 0.0 and c.friction_coefficient > 0.0:
        ft = -c.friction_coefficient * fn * np.clip(vy / c.stiction_velocity, -1.0, 1.0)
    outputs = [-fn, ft, 0.0, fn, xe if touching else 0.0, c.mass, c.damping, K]
    if fn > 0.0:
        s, sd = x - c.surface_x, vx
    if c.mass > 0.0:
        det = 1.0 + h * c.damping / c.mass + h * h * K / c.mass
        s, sd = ((1.0 + h * c.damping / c.mass) * s + h * sd) / det, (
            sd - h * K / c.mass * s) / det
    else:
        s_next = s / (1.0 + h * K / c.damping) if c.damping > 0.0 else 0.0
        s, sd = s_next, (s_next - s) / h
    alpha = c.acceleration_smoothing
    acc = alpha * acc + (1.0 - alpha) * (vx - v_prev) / h
    K_next = c.stiffness * (1.0 + c.stiffness_drift_per_s * t)
    return np.array(outputs, dtype=float), np.array([s, sd, acc, vx, K_next])


@pytest.mark.parametrize("fields", [
    {},
    {"law": "hunt_crossley"},
    {"law": "hunt_crossley", "hunt_crossley_exponent": 2.0,
     "hunt_crossley_reference_penetration": 2e-3},
    {"friction_coefficient": 0.5},
    {"friction_coefficient": 1.0, "stiction_velocity": 1.0},
    {"stiffness_drift_per_s": -0.05, "stiffness": 4.4e4},
    {"mass": 0.0},
    {"mass": 0.0, "damping": 0.0},
    {"mass": 1.0, "damping": 1.0, "acceleration_smoothing": 0.0},
    {"law": "hunt_crossley", "friction_coefficient": 0.3, "stiffness_drift_per_s": 0.01,
     "mass": 0.2, "damping": 40.0, "acceleration_smoothing": 0.7, "stiffness": 6.2e4},
], ids=lambda fields: ",".join(fields) or "default")
def test_bit_identical_to_the_former_python_law(fields):
    """The C++ expressions do the Python law's IEEE operations in its order:
    every output and state, bit for bit, over random tip states around the
    surface (in and out of contact, fast retreats, free relaxation)."""
    wall, context = make_wall(**fields)
    config = wall.config
    rng = np.random.default_rng(7)
    x, v = SURFACE - 1e-3, 0.05
    for n in range(600):
        if n % 200 >= 100:  # jumps: every branch, every step
            x, v = SURFACE + rng.normal(0, 2e-3), rng.normal(0, 0.05)
        tip = np.array([x, rng.normal(0, 0.01), rng.normal(), v,
                        rng.normal(0, 0.02) * rng.choice([0, 1, 100]), rng.normal()])
        wall.GetInputPort("tip_state").FixValue(context, tip)
        # The state is the wall one step ago; the update advances it with
        # this tip state, and the output is the law at the advanced state.
        state = context.get_discrete_state_vector().value().copy()
        advanced = wall.EvalUniquePeriodicDiscreteUpdate(context).get_vector().value().copy()
        _, expected_state = reference_wall_step(
            config, tip, [*state[:4], wall.stiffness_at(state[4])], n * H, H)
        np.testing.assert_array_equal(advanced[:4], expected_state[:4], err_msg=f"step {n}")
        assert wall.stiffness_at(advanced[4]) == expected_state[4]
        expected, _ = reference_wall_step(
            config, tip, [*advanced[:4], wall.stiffness_at(advanced[4])], n * H, H)
        actual = np.concatenate([wall.GetOutputPort(name).Eval(context)
                                 for name in ("force_on_tip", "contact_force", "penetration",
                                              "true_impedance")])
        np.testing.assert_array_equal(actual, expected, err_msg=f"step {n}")
        step_wall(wall, context, n)
        v += H * (20.0 * np.sin(n * 0.05) + actual[0] - 30.0 * v) / 6.8
        x += H * v
