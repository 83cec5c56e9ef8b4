"""Plotting: the helpers draw a log's data on the caller's Axes and return
those lines; importing the module leaves the backend alone; the runner's
figure writers still write their PNGs, without pyplot."""

import os
import subprocess
import sys

import matplotlib.image
import numpy as np
import pytest
from matplotlib.figure import Figure

from drake_contact.app.plotting import (
    plot_contact_figures, plot_force_tracking, plot_impedance, plot_main_signals,
    plot_sensor_figures, plot_signal, plot_tip_errors)
from drake_contact.scenario import Scenario

#: One worker runs this module and its fixture is session-scoped, so the fixture
#: runs once (-n auto; docs/developer/testing.md, "Shared runs").
pytestmark = pytest.mark.xdist_group("test_plotting")

N = 50


@pytest.fixture
def log():
    """A synthetic log: every signal distinct, so a wrong column or key shows."""
    t = np.linspace(0.0, 0.049, N)
    rng = np.random.default_rng(0)
    return {
        "t": t,
        "contact_force_true": 20.0 + np.sin(40 * t),
        "force_filtered": 20.0 + np.cos(40 * t),
        "force_desired": np.where(t < 0.025, 20.0, 10.0),
        "tip_pose_true": np.column_stack([0.5 + t, 1e-3 * np.sin(t), 2e-3 * np.cos(t)]),
        "true_impedance": np.tile([0.1, 100.0, 7000.0], (N, 1)),
        "impedance_rls": np.array([0.1, 100.0, 7000.0]) * (1 + rng.normal(0, 0.1, (N, 3))),
        "mode": (t > 0.01).astype(float),
    }


@pytest.fixture
def scenario():
    scenario = Scenario()
    # Non-zero targets, so an error that ignores them shows.
    scenario.controller.hybrid.y_desired = 2e-4
    scenario.controller.hybrid.phi_desired = -1e-3
    return scenario


def axes(n=1):
    axs = Figure().subplots(n, 1, squeeze=False)[:, 0]
    return axs[0] if n == 1 else axs


def assert_line(line, ax, x, y):
    assert line in ax.get_lines()
    np.testing.assert_array_equal(line.get_xdata(), x)
    np.testing.assert_allclose(line.get_ydata(), y, rtol=1e-12)


def test_plot_signal_draws_a_scalar_signal(log):
    ax = axes()
    line = plot_signal(ax, log, "contact_force_true")
    assert_line(line, ax, log["t"], log["contact_force_true"])
    assert line.get_label() == "contact_force_true"


def test_plot_signal_scales_one_column_and_passes_line_options(log):
    ax = axes()
    line = plot_signal(ax, log, "tip_pose_true", column=2, scale=1e3, label="phi (mrad)",
                       color="tab:red", lw=0.5)
    assert_line(line, ax, log["t"], log["tip_pose_true"][:, 2] * 1e3)
    assert (line.get_label(), line.get_color(), line.get_linewidth()) == (
        "phi (mrad)", "tab:red", 0.5)


def test_plot_signal_asks_for_a_column_of_a_vector_signal(log):
    with pytest.raises(ValueError, match="tip_pose_true.*3 columns.*column="):
        plot_signal(axes(), log, "tip_pose_true")


def test_plot_force_tracking_draws_the_forces_in_the_log(log, scenario):
    ax = axes()
    lines = plot_force_tracking(ax, log, scenario=scenario, label="run A")
    assert_line(lines.true, ax, log["t"], log["contact_force_true"])
    assert_line(lines.filtered, ax, log["t"], log["force_filtered"])
    assert_line(lines.desired, ax, log["t"], log["force_desired"])
    assert lines.measured is None  # no force_measured in this log
    np.testing.assert_array_equal(lines.threshold.get_ydata(), [5.0, 5.0])
    assert lines.true.get_label() == "run A"
    assert len(ax.get_lines()) == 4


def test_plot_force_tracking_leaves_out_what_is_missing(log):
    ax = axes()
    lines = plot_force_tracking(ax, {"t": log["t"], "contact_force_true": log["contact_force_true"],
                                     "force_measured": log["force_filtered"]})
    assert_line(lines.measured, ax, log["t"], log["force_filtered"])
    assert (lines.filtered, lines.desired, lines.threshold) == (None, None, None)
    assert lines.true.get_label() == "true"
    assert len(ax.get_lines()) == 2


def test_plot_tip_errors_on_one_axis(log, scenario):
    ax = axes()
    lines = plot_tip_errors(ax, log, scenario)
    pose = log["tip_pose_true"]
    assert_line(lines.y, ax, log["t"], (pose[:, 1] - 2e-4) * 1e3)
    assert_line(lines.phi, ax, log["t"], (pose[:, 2] + 1e-3) * 1e3)


def test_plot_tip_errors_on_two_axes(log, scenario):
    ax_y, ax_phi = axes(2)
    lines = plot_tip_errors((ax_y, ax_phi), log, scenario)
    assert ax_y.get_lines() == [lines.y] and ax_phi.get_lines() == [lines.phi]
    assert (ax_y.get_ylabel(), ax_phi.get_ylabel()) == ("y error (mm)", "phi error (mrad)")


@pytest.mark.parametrize("truth", [True, False])
def test_plot_impedance_draws_estimates_in_thesis_units(log, truth):
    axs = axes(3)
    lines = plot_impedance(axs, log, "rls", truth=truth, color="tab:green")
    scales = [1.0, 1.0, 1e-3]  # kg, N s/m, kN/m
    for k, (ax, scale) in enumerate(zip(axs, scales)):
        assert_line(lines.estimates[k], ax, log["t"], log["impedance_rls"][:, k] * scale)
        assert lines.estimates[k].get_label() == "rls"
        assert lines.estimates[k].get_color() == "tab:green"
        if truth:
            assert_line(lines.truth[k], ax, log["t"], log["true_impedance"][:, k] * scale)
            assert lines.truth[k].get_linestyle() == "--"
        assert len(ax.get_lines()) == (2 if truth else 1)
    assert (lines.truth is None) == (not truth)
    assert [ax.get_ylabel() for ax in axs] == ["M_e (kg)", "B_e (N s/m)", "K_e (kN/m)"]


def test_importing_keeps_the_users_backend_and_pyplot_out():
    code = ("import sys, matplotlib, drake_contact.app.plotting\n"
            "print('matplotlib.pyplot' in sys.modules, matplotlib.get_backend())\n")
    env = {**os.environ, "MPLBACKEND": "svg"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         check=True).stdout.split()
    assert out == ["False", "svg"]


#: What the runner writes for identify_styrofoam (9 s: the switch is near
#: 8.3 s), with the image size (rows, columns) at 110 dpi.
IDENTIFY_PNGS = {
    "main_signals.png": (990, 880),
    "fig4_4_raw_force.png": (385, 880),
    "fig4_2_switch.png": (440, 880),
    "force_tracking.png": (825, 990),
    "fig6_1_identification.png": (880, 1210),
    "fig6_2_identification.png": (880, 1210),
    "fig6_3_identification.png": (880, 1210),
    "fig6_6_identification.png": (880, 1210),
    "fig6_7_identification.png": (880, 1210),
    "fig6_8_nn_output_error.png": (440, 880),
}


@pytest.fixture(scope="session")
def identify_run(tmp_path_factory):
    from drake_contact.app.runner import run
    from drake_contact.scenario import load_scenario

    scenario = load_scenario("identify_styrofoam", duration=10.0)
    out = tmp_path_factory.mktemp("identify_styrofoam")
    result = run(scenario, out)
    assert result.status == "completed"
    return scenario, result.log, out


def test_the_run_writes_its_figures(identify_run):
    _, _, out = identify_run
    assert {p.name for p in out.glob("*.png")} == set(IDENTIFY_PNGS)
    for name, size in IDENTIFY_PNGS.items():
        image = matplotlib.image.imread(out / name)
        assert image.shape[:2] == size, name
        assert image[..., :3].std() > 0.05, f"{name} is blank"


def test_the_writers_return_what_they_write_and_leave_no_pyplot_figure(identify_run,
                                                                       tmp_path):
    scenario, log, _ = identify_run
    paths = [plot_main_signals(log, scenario, tmp_path),
             *plot_sensor_figures(log, scenario, tmp_path),
             *plot_contact_figures(log, scenario, tmp_path)]
    assert sorted(p.name for p in paths) == sorted(IDENTIFY_PNGS)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(IDENTIFY_PNGS)
    assert "matplotlib.pyplot" not in sys.modules or not sys.modules[
        "matplotlib.pyplot"].get_fignums()


def test_contact_figures_need_a_switch(log, scenario, tmp_path):
    log["mode"][:] = 0
    assert plot_contact_figures(log, scenario, tmp_path) == []
    assert list(tmp_path.iterdir()) == []


def test_min_max_envelope_keeps_a_long_lines_extremes_in_time_order():
    from drake_contact.app.plotting import min_max_envelope
    n = 600_001  # a 600 s run at 1 kHz
    t = np.arange(n) * 1e-3
    y = np.sin(2 * np.pi * 0.05 * t)
    y[123_457] = 9.0     # a one-sample spike
    y[400_003] = -7.0    # and a one-sample dip
    y[500_000:520_000] = np.nan  # a gap of 20 s
    te, ye = min_max_envelope(t, y, 10_000)
    assert len(te) <= 10_000 and np.all(np.diff(te) > 0)
    assert np.nanmax(ye) == 9.0 and np.nanmin(ye) == -7.0
    assert t[123_457] in te and t[400_003] in te
    # Each kept point is a sample of the line, at its own time.
    np.testing.assert_array_equal(ye, y[np.round(te * 1e3).astype(int)])
    # The gap is still a gap; the samples around it are kept.
    inside = (te > 500.1) & (te < 519.9)
    assert inside.any() and np.all(np.isnan(ye[inside]))
    assert np.all(np.isfinite(ye[(te < 499.9) | (te > 520.1)]))
    # A short line is drawn whole.
    short_t, short_y = min_max_envelope(t[:5000], y[:5000], 10_000)
    assert short_t is not None and len(short_y) == 5000


def test_plot_signal_draws_a_long_line_as_its_envelope_only_when_asked(log):
    n = 120_000
    long = {"t": np.arange(n) * 1e-3, "contact_force_true": np.cos(np.arange(n) * 1e-2)}
    ax = axes()
    whole = plot_signal(ax, long, "contact_force_true")
    assert len(whole.get_xdata()) == n
    drawn = plot_signal(ax, long, "contact_force_true", max_points=2000)
    assert len(drawn.get_xdata()) <= 2000
    assert drawn.get_ydata().max() == long["contact_force_true"].max()


def test_envelope_window_keeps_every_lines_envelope_from_a_start_index():
    """The force-tracking figure's window of a long run: the union of each
    line's (and column's) envelope picks from ``start`` on, time counted
    from t0; a short window is the plain window."""
    from drake_contact.app.plotting import _envelope_window, _window, min_max_envelope
    n = 200_001
    t = np.arange(n) * 1e-3
    force = np.sin(t)
    force[150_000] = 50.0                    # a spike in one line only
    pose = np.column_stack([np.cos(t), np.sin(3 * t), np.cos(5 * t)])
    pose[90_000, 2] = -4.0                   # and a dip in one column of another
    log = {"t": t, "contact_force_true": force, "tip_pose_true": pose}
    after = _envelope_window(log, 1000, t0=1.0, keys=("contact_force_true", "tip_pose_true",
                                                      "missing"), max_points=2000)
    assert set(after) == {"t", "contact_force_true", "tip_pose_true"}
    assert after["t"][0] == 0.0 and np.all(np.diff(after["t"]) > 0)
    assert len(after["t"]) <= 4 * 2000
    assert 50.0 in after["contact_force_true"] and -4.0 in after["tip_pose_true"][:, 2]
    # Every line's own envelope of the window is among the kept samples.
    for y in (force[1000:], pose[1000:, 0], pose[1000:, 1], pose[1000:, 2]):
        kept_t, _ = min_max_envelope(t[1000:] - 1.0, y, 2000)
        assert np.all(np.isin(kept_t, after["t"]))
    # The kept samples are the log's, at their own times.
    index = np.round((after["t"] + 1.0) * 1e3).astype(int)
    np.testing.assert_array_equal(after["tip_pose_true"], pose[index])
    # Short: the plain window.
    short = {key: value[:3000] for key, value in log.items()}
    plain = _window(short, short["t"] >= 1.0, t0=1.0, keys=("contact_force_true",))
    same = _envelope_window(short, 1000, t0=1.0, keys=("contact_force_true",))
    for key in plain:
        np.testing.assert_array_equal(same[key], plain[key])
