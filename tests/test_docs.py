"""The documentation site builds with warnings as errors (a broken
cross-reference, a missing page, a docstring that no longer parses or a
scenario section no page lists fails it), runs the tutorial, documents
every public name and every scenario field, and shows the reference
results' committed snapshots (docs/results/) on the pages that include
them."""

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
    """The site, built as ``docs/build.py`` builds it, from the committed
    snapshots."""
    out = tmp_path_factory.mktemp("html")
    start = time.perf_counter()
    built = subprocess.run([sys.executable, str(DOCS / "build.py"), "--out", str(out)],
                           capture_output=True, text=True, timeout=600)
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


def _images(site, name) -> list[str]:
    return re.findall(r'<img [^>]*src="([^"]*)"', page(site, name))


def test_every_page_shows_its_studys_snapshot(site):
    import csv
    with open(DOCS / "results" / "reproduce" / "claims.csv", newline="") as stream:
        scored = list(csv.DictReader(stream))
    reproduction = text(site, "reproduction.html")
    for curly, plain in (("\u2019", "'"), ("\u201c", '"'), ("\u201d", '"')):
        reproduction = reproduction.replace(curly, plain)
    # The claims table: the claims from the code, each seed's values from the snapshot.
    for claim in CLAIMS:
        assert claim.criterion[:60] in reproduction, claim.id
    assert not re.search(r"\bnot run\b", reproduction)  # every claim has its values
    first = scored[0]
    assert first["values"].split("; ")[0] in reproduction
    assert "metrics.json" not in page(site, "reproduction.html")  # the run list is left out
    # Sections named whole though their titles have a comma.
    assert "The neural controller, window by window" not in reproduction
    assert "nn_rubber_sine" in reproduction and "first contact loss after contact" in reproduction
    for name, study, figures in (("reproduction.html", "reproduce", 40),
                                 ("studies/benchmark.html", "benchmark", 6),
                                 ("studies/stability-maps.html", "stability_nn", 3),
                                 ("studies/robust-control.html", "robust_nn", 2),
                                 ("studies/identification.html", "identify_any", 2),
                                 ("studies/faults.html", "faults", 0)):
        assert "The reference results: measured at commit" in text(site, name), name
        assert "not in this build" not in text(site, name), name
        # Sphinx copies each snapshot figure to _images/ under its own name.
        pngs = {p.stem for p in (DOCS / "results" / study).rglob("*.png")}
        shown = [src for src in _images(site, name)
                 if any(Path(src).stem.startswith(stem) for stem in pngs)]
        assert len(shown) >= figures, (name, len(shown))
        for src in shown:
            assert (site / Path(name).parent / src).resolve().is_file(), (name, src)


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
