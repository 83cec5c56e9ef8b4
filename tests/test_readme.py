"""The README's "Use it from Python" example runs, and its logs are the
command line's, bit for bit, whatever the diagrams are named."""

import os
import re
import subprocess
import sys
from pathlib import Path

import matplotlib
import numpy as np

REPO = Path(__file__).resolve().parents[1]


def readme_example() -> str:
    text = (REPO / "README.md").read_text()
    section = text.split("## Use it from Python", 1)[1]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_the_example_is_short():
    code = [line for line in readme_example().splitlines() if line.strip()]
    assert len(code) <= 15, len(code)


def test_the_readme_example_gives_the_command_lines_logs(tmp_path):
    matplotlib.use("Agg")  # the example leaves the backend to the user
    namespace = {}
    exec(compile(readme_example(), "README.md", "exec"), namespace)
    result = namespace["result"]
    assert result.status == "completed"
    assert namespace["torque"].shape == (3, 401)  # the user's own 10 ms logger
    assert namespace["station"].get_name() == "my_arm"

    out = tmp_path / "cli"
    subprocess.run([sys.executable, "-m", "drake_contact", "run", "push_constant", "--seed", "3",
                    "--out", str(out), "--no-figures"], check=True, capture_output=True,
                   env=dict(os.environ, MPLBACKEND="Agg"), timeout=600)
    with np.load(out / "log.npz") as cli:
        assert set(cli.files) == set(result.log)
        for key in cli.files:
            assert cli[key].tobytes() == result.log[key].tobytes(), key
    # The noise is there (not a zero-noise coincidence): the measured force
    # differs from sample to sample at rest.
    rest = result.log["t"] < 1.0
    assert np.std(result.log["force_measured"][rest]) > 0.1


def test_noise_does_not_depend_on_the_diagrams_names():
    import drake_contact as dc
    from pydrake.systems.framework import DiagramBuilder

    def force(outer, inner):
        scenario = dc.load_scenario("push_constant", duration=0.5, seed=5)
        builder = DiagramBuilder()
        station = builder.AddNamedSystem(inner, dc.MakeContactDiagram(scenario))
        loggers = dc.AddSignalLoggers(builder, station)
        diagram = builder.Build()
        diagram.set_name(outer)
        return dc.simulate(diagram, loggers).log["force_measured"]
    reference = force("run", "station")
    np.testing.assert_array_equal(force("x", "y"), reference)
    np.testing.assert_array_equal(force("my_lab", "arm_under_test"), reference)
    other_seed = dc.simulate_scenario(dc.load_scenario("push_constant", duration=0.5, seed=6))
    assert not np.array_equal(other_seed.log["force_measured"], reference)
