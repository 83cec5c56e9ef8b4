"""The documentation site builds with warnings as errors (a broken
cross-reference, a missing page, a docstring that no longer parses or a
scenario section no page lists fails it), runs the tutorial, documents
every public name and every scenario field, and shows a long study's
results when they are there and the command that makes them when not."""

import os
import re
import subprocess
import sys
import time
from html.parser import HTMLParser
from pathlib import Path

import pytest

pytest.importorskip("sphinx", reason="building the documentation needs the docs extra "
                    "(pip install '.[test]')")
pytest.importorskip("myst_nb", reason="building the documentation needs myst-nb "
                    "(pip install '.[test]')")

REPO = Path(__file__).resolve().parents[1]
DOCS = REPO / "docs"
sys.path.insert(0, str(DOCS / "_ext"))

import drake_contact as dc  # noqa: E402
from drake_contact.app.claims import CLAIMS  # noqa: E402
from drake_contact_docs import _study_markdown, scenario_rows  # noqa: E402

pytestmark = pytest.mark.xdist_group("docs")

REPORT = """# drake_contact: the thesis reproduced

1 of 1 results reproduced.

## The thesis's claims

| id | verdict |
|---|---|
| S3 | reproduced |

## Beyond the thesis

| experiment | result |
|---|---|
| sensor noise | PASS |

## Runs

- `sensor_spectrum` seed 0: exit 0 ([metrics](sensor_spectrum/seed_0/metrics.json))

## Figures

### Fig 4.4: sensor noise

![sensor_spectrum/seed_0/fig4_4_raw_force.png](sensor_spectrum/seed_0/fig4_4_raw_force.png)
"""


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """The site, built as ``docs/build.py`` builds it, with one study made
    (a small stand-in for the reproduction's report) and the others not."""
    generated = tmp_path_factory.mktemp("generated")
    figure = generated / "reproduce" / "sensor_spectrum" / "seed_0" / "fig4_4_raw_force.png"
    figure.parent.mkdir(parents=True)
    figure.write_bytes((DOCS / "_static" / "force_tracking.png").read_bytes())
    (generated / "reproduce" / "report.md").write_text(REPORT)
    (generated / "reproduce" / "claims.csv").write_text(
        "id,thesis_lines,figures,claim,runs,criterion,seed,values,holds,verdict,cause\n"
        "S3,344,4.4,x,x,x,0,p99_n=1.917,True,reproduced,\n")
    out = tmp_path_factory.mktemp("html")
    start = time.perf_counter()
    built = subprocess.run([sys.executable, str(DOCS / "build.py"), "--out", str(out)],
                           capture_output=True, text=True, timeout=600,
                           env=dict(os.environ, DRAKE_CONTACT_DOCS_GENERATED=str(generated)))
    print(f"documentation built in {time.perf_counter() - start:.0f} s")
    assert built.returncode == 0, built.stdout[-3000:] + built.stderr[-5000:]
    return out


def page(site, name) -> str:
    return (site / name).read_text()


class _Text(HTMLParser):
    """The text a reader sees in a page's article, whitespace collapsed."""

    def __init__(self):
        super().__init__()
        self.parts, self._skip = [], 0

    def handle_starttag(self, tag, attrs):
        self._skip += tag in ("script", "style")

    def handle_endtag(self, tag):
        self._skip -= tag in ("script", "style")

    def handle_data(self, data):
        if not self._skip:
            self.parts.append(data)


def text(site, name) -> str:
    parser = _Text()
    parser.feed(page(site, name))
    return " ".join(" ".join(parser.parts).split())


def test_every_page_is_built(site):
    for name in ("index", "getting-started", "tutorial", "reproduction", "user-guide/cli",
                 "user-guide/python", "user-guide/scenarios", "user-guide/signals", "extending",
                 "studies/identification", "studies/robust-control", "studies/stability-maps",
                 "studies/benchmark", "studies/faults", "modelling", "developer/index",
                 "developer/testing", "developer/performance", "api", "changelog"):
        assert (site / f"{name}.html").exists(), name


def test_the_api_reference_lists_exactly_the_public_names():
    listed = re.findall(r"^   (\w+)$", (DOCS / "api.md").read_text().split("## Modules")[0],
                        re.M)
    assert listed == list(dc.__all__)


def test_every_public_name_has_a_page_with_its_docstring(site):
    for name in dc.__all__:
        path = site / "_autosummary" / f"drake_contact.{name}.html"
        assert path.exists(), name
        doc = getattr(dc, name).__doc__
        if doc is None or isinstance(getattr(dc, name), dict):
            continue  # a constant (FAULT_KINDS) documents itself by its comment
        first = re.sub(r":\w+:`~?([^`]+)`", r"\1", doc.strip().split("\n\n")[0])
        words = " ".join(re.findall(r"\w+", first)[:5])
        rendered = " ".join(re.findall(r"\w+", text(site, f"_autosummary/drake_contact.{name}.html")))
        assert words in rendered, (name, words)


def test_every_scenario_field_is_in_the_reference(site):
    rendered = text(site, "user-guide/scenarios.html")
    fields = [path for path, *_ in scenario_rows(dc.Scenario, "")]
    assert len(fields) > 150
    missing = [path for path in fields if path not in rendered]
    assert not missing, missing


def test_the_field_reference_reads_the_comments_of_the_code():
    rows = {path: (kind, default, doc) for path, kind, default, doc
            in scenario_rows(dc.Scenario, "")}
    assert rows["environment.stiffness"] == ("float", "`7000.0`",
                                             "Stiffness K_e (N/m). Styrofoam about 7e3, rubber "
                                             "4.4e4-6.2e4 (thesis).")
    assert rows["scoring.window_end_s"][2] == rows["scoring.window_start_s"][2]  # one comment
    assert rows["identifiers"][0].startswith("list of")
    assert "identifiers[i].name" in rows


def test_the_tutorial_is_rendered_with_its_figures(site):
    tutorial = page(site, "tutorial.html")
    assert "dc.load_scenario" in tutorial
    assert re.search(r'<img [^>]*src="[^"]*\.png"', tutorial)


def test_the_station_signals_are_generated_from_the_station(site):
    rendered = text(site, "user-guide/signals.html")
    station = dc.MakeContactDiagram(dc.load_scenario("nn_styrofoam"))
    for name in station.signals:
        assert name in rendered, name


def test_a_made_study_is_shown_and_a_missing_one_names_its_command(site):
    reproduction = page(site, "reproduction.html")
    assert "sensor noise" in reproduction and "PASS" in reproduction
    # The claims table: the claims from the code, a run's values where it has them.
    claims = text(site, "reproduction.html")
    for curly, plain in (("\u2019", "'"), ("\u201c", '"'), ("\u201d", '"')):
        claims = claims.replace(curly, plain)
    for claim in CLAIMS:
        assert claim.criterion[:60] in claims, claim.id
    assert "p99_n=1.917 (holds)" in claims and claims.count("not run") >= len(CLAIMS) - 1
    assert re.search(r'<img [^>]*src="[^"]*fig4_4_raw_force[^"]*\.png"', reproduction)
    assert "metrics.json" not in reproduction  # the run list is left out
    maps = text(site, "studies/stability-maps.html")
    assert "python docs/build.py --figures --study stability_nn" in maps
    assert "<img" not in page(site, "studies/stability-maps.html").split("stability_hybrid")[-1]


def test_a_study_keeps_its_tables_and_points_its_images_at_its_folder():
    converted = _study_markdown(REPORT, "../_generated/reproduce", {"Runs"}, set())
    assert "# drake_contact" not in converted
    assert "| sensor noise | PASS |" in converted
    assert "**Fig 4.4: sensor noise**" in converted
    assert "](../_generated/reproduce/sensor_spectrum/seed_0/fig4_4_raw_force.png)" in converted
    assert "metrics.json" not in converted
    only = _study_markdown(REPORT, "x", set(), {"Figures"})
    assert "PASS" not in only and "Fig 4.4" in only


def test_the_readme_is_one_screen_and_starts_with_the_commands():
    readme = (REPO / "README.md").read_text().splitlines()
    assert len(readme) <= 250
    first = "\n".join(readme[:40])
    assert "pip install -c constraints.txt . && .venv/bin/drake-contact reproduce" in first
    assert "'.[test]' ./examples/jt_pi_controller ./examples/learned_force_policy && .venv/bin/pytest -q" in first
