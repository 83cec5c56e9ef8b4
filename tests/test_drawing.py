"""Drawing a diagram: Drake's DOT text, Graphviz's SVG, the file name checks
and ``drake-contact run --graphviz``."""

import shutil
import xml.etree.ElementTree as ET

import pytest

from conftest import skip_unless_tool
from drake_contact.app.cli import main
from drake_contact.app.drawing import diagram_dot, render_svg, write_diagram
from drake_contact.diagram import MakeContactDiagram
from drake_contact.errors import ScenarioError
from drake_contact.scenario import load_scenario

@pytest.fixture(scope="module")
def diagram():
    return MakeContactDiagram(load_scenario("push_constant"))


def test_dot_file_names_the_station_systems(diagram, tmp_path):
    path = write_diagram(diagram, tmp_path / "sub" / "d.dot")
    text = path.read_text()
    assert path == tmp_path / "sub" / "d.dot"
    assert text.lstrip().startswith("digraph")
    for name in ("force_sensor", "wall", "controller", "plant"):
        assert f"name={name}" in text, name


def test_max_depth_zero_draws_the_diagram_as_one_block(diagram):
    whole, one_block = diagram_dot(diagram), diagram_dot(diagram, max_depth=0)
    assert "name=force_sensor" in whole
    assert "name=force_sensor" not in one_block
    assert f"name={diagram.get_name()}" in one_block


@skip_unless_tool("dot", "the diagram drawn as SVG")
def test_svg_file_is_valid_svg(diagram, tmp_path):
    path = write_diagram(diagram, tmp_path / "d.svg")
    root = ET.parse(path).getroot()
    assert root.tag == "{http://www.w3.org/2000/svg}svg"
    assert "force_sensor" in path.read_text()


def test_svg_without_dot_is_one_clear_error(diagram, tmp_path, monkeypatch):
    monkeypatch.setattr(shutil, "which", lambda name: None)
    assert render_svg("digraph { a -> b }") is None
    with pytest.raises(ScenarioError, match="apt-get install graphviz") as error:
        write_diagram(diagram, tmp_path / "d.svg")
    assert "\n" not in str(error.value)
    assert not (tmp_path / "d.svg").exists()


@pytest.mark.parametrize("name", ["d.png", "d.gv", "diagram"])
def test_other_extensions_are_refused(diagram, tmp_path, name):
    with pytest.raises(ScenarioError, match=r"must end in \.dot or \.svg"):
        write_diagram(diagram, tmp_path / name)
    assert not (tmp_path / name).exists()


# push_constant needs duration >= its 0.5 s settle window.
def _run(out, *extra):
    return main(["run", "push_constant", "--out", str(out), "--duration", "0.5",
                 "--no-figures", *extra])


def test_run_writes_the_diagram(tmp_path):
    out = tmp_path / "out"
    assert _run(out, "--graphviz", str(out / "d.dot")) == 0
    assert "name=force_sensor" in (out / "d.dot").read_text()
    assert (out / "metrics.json").is_file()


def test_run_with_a_bad_diagram_file_exits_2_before_simulating(tmp_path, capsys):
    out = tmp_path / "out"
    assert _run(out, "--graphviz", str(tmp_path / "d.png")) == 2
    stderr = capsys.readouterr().err
    assert stderr.count("\n") == 1 and "graphviz" in stderr and ".dot or .svg" in stderr
    assert not (out / "metrics.json").exists()
