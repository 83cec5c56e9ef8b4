"""The drake-contact command as a user runs it, and the installed wheel."""

import json
import re
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def drake_contact(*args, cwd):
    return subprocess.run([sys.executable, "-m", "drake_contact", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=300)


def test_list_names_the_bundled_scenarios(tmp_path):
    result = drake_contact("list", cwd=tmp_path)
    assert result.returncode == 0
    names = [line.split()[0] for line in result.stdout.splitlines()]
    assert names == sorted(names) and {"push_constant", "sensor_spectrum"} <= set(names)


def test_run_writes_the_outputs(tmp_path):
    out = tmp_path / "out"
    result = drake_contact("run", "push_constant", "--out", str(out), "--duration", "0.5",
                           "--seed", "2", "--set", "environment.stiffness=6.2e4", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert result.stderr == ""  # quiet off a terminal
    assert "completed" in result.stdout and "real-time factor" in result.stdout
    for name in ("scenario.yaml", "log.npz", "metrics.json", "main_signals.png"):
        assert (out / name).is_file()
    resolved = (out / "scenario.yaml").read_text()
    assert "stiffness: 62000.0" in resolved and "seed: 2" in resolved
    assert json.loads((out / "metrics.json").read_text())["simulated_time_s"] == 0.5


BAD_INPUTS = [
    (["--set", "environment.stiffness=-1"], "environment.stiffness = -1.0 is out of range"),
    (["--set", "environment.stiffness=0"], "environment.stiffness = 0.0 is out of range"),
    (["--set", "environment.damping=-2"], "environment.damping = -2.0 is out of range"),
    (["--set", "environment.mass=-1"], "environment.mass = -1.0 is out of range"),
    (["--set", "arm.time_step=0.0007"], "arm.time_step = 0.0007 is out of range: must be 0.001 / 2**k s"),
    (["--set", "environment.stifness=1"], "environment.stifness is not a scenario key"),
    (["--set", "controller.name=magic"], "controller.name = 'magic' is unknown"),
    (["--set", "nokey"], "--set 'nokey' is malformed"),
    (["--duration", "-1"], "simulation.duration = -1.0 is out of range"),
    # Logs held in memory that could not fit: refused, with this machine's limit.
    (["--set", "simulation.duration=1e12"], "simulation.duration = 1e+12 is out of range: its "
     "1 kHz logs"),
]


@pytest.mark.parametrize("command", [["run", "push_constant"], ["reproduce", "--quick"],
                                     ["sweep", "stability_nn", "--quick"]])
def test_an_output_folder_that_cannot_be_made_exits_2_with_one_line(tmp_path, command):
    result = drake_contact(*command, "--out", "/proc/x/y", cwd=tmp_path)
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1 and "--out = /proc/x/y: cannot write there" in \
        result.stderr
    assert "Traceback" not in result.stderr


@pytest.mark.parametrize("extra,message", BAD_INPUTS)
def test_bad_input_exits_2_with_one_line(tmp_path, extra, message):
    result = drake_contact("run", "push_constant", "--out", str(tmp_path / "o"), *extra,
                           cwd=tmp_path)
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1 and message in result.stderr
    assert "Traceback" not in result.stderr
    assert not (tmp_path / "o" / "log.npz").exists()  # refused before simulating


def test_malformed_file_and_unknown_name_exit_2(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("environment:\n  stiffness: [7000\n")
    for scenario, message in ((str(bad), "malformed YAML"),
                              ("no_such_scenario", "is neither a file nor a bundled")):
        result = drake_contact("run", scenario, "--out", str(tmp_path / "o"), cwd=tmp_path)
        assert result.returncode == 2 and result.stderr.count("\n") == 1
        assert message in result.stderr and "Traceback" not in result.stderr
    result = drake_contact("run", cwd=tmp_path)  # missing arguments
    assert result.returncode == 2 and "Traceback" not in result.stderr


@pytest.mark.parametrize("args, hint", [
    (["run", "identify_styrofom"], "(did you mean 'identify_styrofoam'?)"),
    (["run", "push_constant", "--set", "environment.stifness=3"], "(did you mean 'stiffness'?)"),
    (["run", "push_constant", "--set", "controller.name=hybird"], "(did you mean 'hybrid'?)"),
    (["sweep", "robust_n"], "(did you mean 'robust_nn'?)"),
    (["run", "push_constant", "--set", "environment.xyzzy=3"], None),
])
def test_a_misspelt_name_or_key_gets_a_did_you_mean(tmp_path, args, hint):
    result = drake_contact(*args, "--out", str(tmp_path / "o"), cwd=tmp_path)
    assert result.returncode == 2 and result.stderr.count("\n") == 1
    assert "Traceback" not in result.stderr
    if hint is None:  # nothing close: no guess
        assert "did you mean" not in result.stderr
    else:
        assert hint in result.stderr


def test_version_and_help_read_as_plain_text(tmp_path):
    from importlib.metadata import version
    result = drake_contact("--version", cwd=tmp_path)
    assert result.returncode == 0
    assert result.stdout.strip() == f"drake-contact {version('drake_contact')}"
    result = drake_contact("--help", cwd=tmp_path)
    assert result.returncode == 0 and "``" not in result.stdout and "--version" in result.stdout


def test_divergence_exits_3_with_time_and_keeps_logs(tmp_path):
    out = tmp_path / "o"
    result = drake_contact("run", "push_constant", "--out", str(out), "--no-figures",
                           "--set", "environment.stiffness=1e9",
                           "--set", "controller.push.start_time=0", cwd=tmp_path)
    assert result.returncode == 3
    assert re.search(r"diverged at t = 0\.\d+ s: the contact force", result.stderr)
    assert (out / "log.npz").is_file() and (out / "metrics.json").is_file()


def test_a_non_editable_install_finds_models_from_another_directory(tmp_path):
    """Build the wheel, install it into a fresh folder, and load a bundled
    scenario from an unrelated working directory."""
    wheels = tmp_path / "wheels"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w",
                    str(wheels), str(REPO)], check=True, timeout=600)
    (wheel,) = wheels.glob("drake_contact-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    assert "drake_contact/models/arm3dof.urdf" in names
    assert "drake_contact/models/scenarios/push_constant.yaml" in names
    site = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target",
                    str(site), str(wheel)], check=True, timeout=600)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    code = ("import drake_contact.resources as r, drake_contact.scenario as s;"
            "print(r.models_dir()); s.load_scenario('push_constant')")
    env = dict(os.environ, PYTHONPATH=str(site))
    result = subprocess.run([sys.executable, "-c", code], cwd=elsewhere, env=env,
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert Path(result.stdout.strip()) == site / "drake_contact" / "models"
