"""Sweep figures on synthetic rows (no simulation): the statistics over seeds,
the heat map's cells and crosses, facets, the line plot's means, the PNGs and
the HTML report; rows read back from ``results.csv`` give the same numbers."""

import csv
import dataclasses as dc
import html.parser
import math

import matplotlib.image
import numpy as np
import pytest
from matplotlib.figure import Figure

from drake_contact.app.sweep_figures import (
    aggregate, markdown_map, plot_heat_map, plot_metric_line, plot_sweep_map, write_sweep_figures,
    write_sweep_html)

X, Y, Z = "environment.stiffness", "controller.nn.learning_rate", "environment.damping"
METRIC = "force_rmse_n"
STIFFNESS = [1e3, 1e4, 1e5, 1e6]  # spans 1000: a log axis by default
RATES = [0.01, 0.1, 1.0]
SEEDS = [0, 1]
#: The point that diverged in seed 1 (no metric there) and the one that lost
#: contact in seed 0, as (rate, stiffness).
DIVERGED, LOST = (0.1, 1e5), (1.0, 1e3)


def rmse(rate, stiffness, seed):
    """Distinct per cell and seed, so a swapped axis or seed shows."""
    return 1.0 + RATES.index(rate) * 10 + STIFFNESS.index(stiffness) + 0.5 * seed ** 2


def make_rows(damping=None, offset=0.0):
    rows = []
    # Shuffled order of the grid: the sort is the module's job.
    for rate in reversed(RATES):
        for stiffness in STIFFNESS[::-1]:
            for seed in SEEDS:
                status, value = "completed", rmse(rate, stiffness, seed) + offset
                if (rate, stiffness) == DIVERGED and seed == 1:
                    status, value = "diverged", None
                if (rate, stiffness) == LOST and seed == 0:
                    status = "lost_contact"
                row = {"point": f"k{stiffness:g}_lr{rate:g}_d{damping}_s{seed}",
                       X: stiffness, Y: rate}
                if damping is not None:
                    row[Z] = damping
                row.update(seed=seed, status=status, message="<b>&", wall_time_s=1.5,
                           **{METRIC: value, "contact_losses": int(status == "lost_contact"),
                              "stable": status != "diverged",
                              "identification_error_rls_matched.stiffness": None})
                rows.append(row)
    return rows


@pytest.fixture
def rows():
    return make_rows()


def expected_means():
    """Means over seeds by hand, [rate, stiffness]."""
    means = np.array([[np.mean([rmse(r, k, s) for s in SEEDS]) for k in STIFFNESS]
                      for r in RATES])
    means[RATES.index(DIVERGED[0]), STIFFNESS.index(DIVERGED[1])] = rmse(*DIVERGED, 0)
    return means


def as_csv_rows(rows, tmp_path):
    """The rows as the runner writes ``results.csv`` and DictReader reads it."""
    path = tmp_path / "results.csv"
    columns = list(dict.fromkeys(k for row in rows for k in row))
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, columns)
        writer.writeheader()
        writer.writerows([{k: "" if v is None else v for k, v in row.items()} for row in rows])
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


# ----------------------------------------------------------- aggregate


def test_aggregate_means_stds_and_counts(rows):
    stats = aggregate(rows, [Y, X], METRIC)
    assert list(stats) == [(r, k) for r in RATES for k in STIFFNESS]  # numeric order
    for (rate, stiffness), cell in stats.items():
        values = [rmse(rate, stiffness, s) for s in SEEDS]
        if (rate, stiffness) == DIVERGED:
            values = values[:1]
        assert cell["mean"] == pytest.approx(np.mean(values))
        assert cell["min"] == min(values) and cell["max"] == max(values)
        assert cell["count"] == len(values) and cell["n_runs"] == 2
        if len(values) > 1:
            assert cell["std"] == pytest.approx(np.std(values, ddof=1))
        else:
            assert math.isnan(cell["std"])
        assert cell["n_diverged"] == ((rate, stiffness) == DIVERGED)
        assert cell["n_lost_contact"] == ((rate, stiffness) == LOST)
        assert cell["n_failed"] == 0
        assert cell["n_completed"] == 2 - cell["n_diverged"] - cell["n_lost_contact"]


def test_aggregate_pools_fields_not_grouped_by(rows):
    stats = aggregate(rows, [X], METRIC)
    assert list(stats) == [(k,) for k in STIFFNESS]
    finite = [rmse(r, 1e5, s) for r in RATES for s in SEEDS if not ((r, 1e5) == DIVERGED and s)]
    assert stats[(1e5,)]["mean"] == pytest.approx(np.mean(finite))
    assert stats[(1e5,)]["count"] == 5 and stats[(1e5,)]["n_diverged"] == 1


def test_aggregate_ignores_non_finite_values_and_reads_booleans():
    rows = [{"a": 1.0, "m": v, "stable": b, "status": "completed"}
            for v, b in ((2.0, True), (math.nan, False), (math.inf, True), (None, None),
                         ("", True), (4.0, False))]
    cell = aggregate(rows, ["a"], "m")[(1.0,)]
    assert (cell["mean"], cell["count"], cell["n_runs"]) == (3.0, 2, 6)
    stable = aggregate(rows, "a", "stable")[(1.0,)]
    assert (stable["mean"], stable["count"]) == (pytest.approx(0.6), 5)
    empty = aggregate(rows[1:2], ["a"], "m")[(1.0,)]
    assert empty["count"] == 0 and math.isnan(empty["mean"]) and math.isnan(empty["max"])


def test_aggregate_reads_results_csv_the_same(rows, tmp_path):
    from_csv = aggregate(as_csv_rows(rows, tmp_path), [Y, X], METRIC)
    direct = aggregate(rows, [Y, X], METRIC)
    assert list(from_csv) == list(direct)
    for key in direct:
        np.testing.assert_equal(from_csv[key], direct[key])


def test_aggregate_sorts_numerically_then_categories():
    rows = [{"f": v, "m": 1.0} for v in ("20", "3", "1e3", "b", "a", 3.0)]
    assert list(aggregate(rows, ["f"], "m")) == [(3.0,), (20.0,), (1e3,), ("a",), ("b",)]


# ------------------------------------------------------------ heat map


def test_markdown_maps_a_grid_and_a_line_with_their_bad_runs(rows):
    grid = markdown_map(rows, METRIC, X, Y, title="RMSE")
    top = rmse(RATES[0], STIFFNESS[0], 0), rmse(RATES[0], STIFFNESS[0], 1)
    assert f"| 0.01 | {'%.3g' % np.mean(top)} |" in grid
    assert f"{'%.3g' % rmse(*LOST, 0)}" in grid and "lost 1/2" in grid
    assert "diverged 1/2" in grid
    line = markdown_map(rows, METRIC, X, None, title="RMSE")
    assert line.startswith("**RMSE** (over seeds; environment.stiffness down)")
    # One row per stiffness: the mean over rates and seeds, its range, the runs.
    values = [rmse(r, STIFFNESS[-1], s) for r in RATES for s in SEEDS]
    assert (f"| {'%.3g' % np.mean(values)} | {'%.3g' % min(values)} to {'%.3g' % max(values)}"
            f" | 6 |") in line
    assert line.count("\n| ") == len(STIFFNESS) + 1
    faceted = markdown_map(rows, METRIC, X, None, facet=Y)
    assert faceted.count("| runs |") == len(RATES)


def test_heat_map_cells_and_crosses(rows):
    ax = Figure().subplots()
    heat = plot_heat_map(ax, rows, METRIC, X, Y)
    assert heat.x_values == STIFFNESS and heat.y_values == RATES
    np.testing.assert_allclose(heat.values, expected_means(), rtol=1e-12)
    expected = np.zeros((3, 4), dtype=bool)
    expected[RATES.index(DIVERGED[0]), STIFFNESS.index(DIVERGED[1])] = True
    expected[RATES.index(LOST[0]), STIFFNESS.index(LOST[1])] = True
    np.testing.assert_array_equal(heat.marked, expected)
    # The mesh shows the same means, one cell per grid point.
    np.testing.assert_allclose(np.ma.filled(heat.image.get_array(), np.nan).reshape(3, 4),
                               expected_means())
    # Log axes by default (both span more than 20), ticks at the grid's values.
    assert ax.get_xscale() == "log" and ax.get_yscale() == "log"
    np.testing.assert_allclose(ax.get_xticks(), STIFFNESS)
    # In the field's unit, named on the axis: 1-1000 kN/m, not 1e+03-1e+06.
    assert [t.get_text() for t in ax.get_xticklabels()] == ["1", "10", "100", "1000"]
    assert ax.get_xlabel() == "environment.stiffness (kN/m)"
    assert [t.get_text() for t in ax.get_yticklabels()] == ["0.01", "0.1", "1"]
    # A red cross on the diverged cell, an orange one on the lost contact.
    red, orange = heat.crosses
    assert red.get_marker() == orange.get_marker() == "x"
    assert (list(red.get_xdata()), list(red.get_ydata())) == ([DIVERGED[1]], [DIVERGED[0]])
    assert (list(orange.get_xdata()), list(orange.get_ydata())) == ([LOST[1]], [LOST[0]])
    assert red.get_color() != orange.get_color()
    assert heat.colorbar.ax.get_ylabel() == METRIC


def test_heat_map_annotates_mean_and_std(rows):
    heat = plot_heat_map(Figure().subplots(), rows, METRIC, X, Y)
    i, j = RATES.index(0.01), STIFFNESS.index(1e4)
    values = [rmse(0.01, 1e4, s) for s in SEEDS]
    assert heat.texts[i][j].get_text() == "%.3g\n±%.2g" % (np.mean(values), np.std(values, ddof=1))
    # One finite seed: the mean alone.
    i, j = RATES.index(DIVERGED[0]), STIFFNESS.index(DIVERGED[1])
    assert heat.texts[i][j].get_text() == "%.3g" % rmse(*DIVERGED, 0)


def test_heat_map_linear_axes_and_missing_cells(rows):
    kept = [r for r in rows if not (r[X] == 1e6 and r[Y] == 0.01)]
    heat = plot_heat_map(Figure().subplots(), kept, METRIC, X, Y, log_x=False, log_y=False)
    assert heat.image.axes.get_xscale() == "linear"
    assert np.isnan(heat.values[0, 3]) and not heat.marked[0, 3]
    assert np.isfinite(heat.values).sum() == 11


def test_heat_map_where_selects_a_facet():
    rows = make_rows(damping=10.0) + make_rows(damping=50.0, offset=100.0)
    heat = plot_heat_map(Figure().subplots(), rows, METRIC, X, Y, where={Z: "50"})
    np.testing.assert_allclose(heat.values, expected_means() + 100.0)


def test_facets_one_panel_per_value():
    rows = make_rows(damping=10.0) + make_rows(damping=50.0, offset=100.0)
    fig = Figure()
    panels = plot_sweep_map(fig, rows, {"metric": METRIC, "x": X, "y": Y, "facet": Z})
    assert len(panels) == 2
    np.testing.assert_allclose(panels[0].values, expected_means())
    np.testing.assert_allclose(panels[1].values, expected_means() + 100.0)
    titles = [ax.get_title() for ax in fig.axes if ax.get_title()]
    assert titles == [f"{Z} = 10 N s/m", f"{Z} = 50 N s/m"]
    # No facet: the other varied field is pooled, one panel.
    (pooled,) = plot_sweep_map(Figure(), rows, {"metric": METRIC, "x": X, "y": Y})
    np.testing.assert_allclose(pooled.values, expected_means() + 50.0)


# ----------------------------------------------------------- line plot


def test_line_plot_means_per_group(rows):
    ax = Figure().subplots()
    lines = plot_metric_line(ax, rows, METRIC, X, group=Y)
    assert len(lines) == len(RATES)
    for line, means, rate in zip(lines, expected_means(), RATES):
        np.testing.assert_array_equal(line.get_xdata(), STIFFNESS)
        np.testing.assert_allclose(line.get_ydata(), means, rtol=1e-12)
        assert line.get_label() == f"{Y} = {rate:.3g}"
    assert ax.get_xscale() == "log"
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "band: min–max over seeds" in legend
    crosses = [line for line in ax.get_lines() if line.get_marker() == "x"]
    points = sorted((x, y) for c in crosses for x, y in zip(c.get_xdata(), c.get_ydata()))
    assert points == sorted([(DIVERGED[1], rmse(*DIVERGED, 0)),
                             (LOST[1], np.mean([rmse(*LOST, s) for s in SEEDS]))])


def test_line_plot_band_is_min_max_or_std(rows):
    ax = Figure().subplots()
    plot_metric_line(ax, rows, METRIC, Y, group=None, spread="std")
    assert "band: ±1 std over seeds" in [t.get_text() for t in ax.get_legend().get_texts()]
    band = ax.collections[0].get_paths()[0].vertices
    stats = aggregate(rows, [Y], METRIC)
    lows = [s["mean"] - s["std"] for s in stats.values()]
    highs = [s["mean"] + s["std"] for s in stats.values()]
    assert band[:, 1].min() == pytest.approx(min(lows))
    assert band[:, 1].max() == pytest.approx(max(highs))
    with pytest.raises(ValueError, match="spread"):
        plot_metric_line(ax, rows, METRIC, X, spread="iqr")


def test_line_plot_lines_per_remaining_field_in_a_map(rows):
    (lines,) = plot_sweep_map(Figure(), rows, {"metric": METRIC, "x": X})
    assert [line.get_label() for line in lines] == [f"{Y} = {r:.3g}" for r in RATES]
    np.testing.assert_allclose([line.get_ydata() for line in lines], expected_means())


# ------------------------------------------------------------- writers


@dc.dataclass
class MapSpec:
    metric: str
    x: str
    y: str | None = None
    facet: str | None = None
    title: str | None = None
    log_x: bool | None = None
    log_y: bool | None = None


def test_write_sweep_figures_writes_one_png_per_map(tmp_path):
    rows = make_rows(damping=10.0) + make_rows(damping=50.0, offset=100.0)
    maps = [MapSpec(METRIC, X, Y), {"metric": METRIC, "x": X, "y": Y, "facet": Z},
            MapSpec(METRIC, X, title="RMSE"), MapSpec("contact_losses", Y, facet=Z),
            {"metric": "stable", "x": Y, "y": "", "facet": "", "title": ""}]  # "": absent
    paths = write_sweep_figures(rows, maps, tmp_path / "figs")
    assert [p.name for p in paths] == [
        "map_force_rmse_n_environment_stiffness_controller_nn_learning_rate.png",
        "map_force_rmse_n_environment_stiffness_controller_nn_learning_rate"
        "_by_environment_damping.png",
        "map_force_rmse_n_environment_stiffness.png",
        "map_contact_losses_controller_nn_learning_rate_by_environment_damping.png",
        "map_stable_controller_nn_learning_rate.png"]
    images = [matplotlib.image.imread(p) for p in paths]
    assert all(image.shape[0] > 100 and image.std() > 0 for image in images)
    assert images[1].shape[1] > images[0].shape[1]  # two panels side by side


def test_write_sweep_html_embeds_figures_and_every_row(rows, tmp_path):
    figures = write_sweep_figures(rows, [MapSpec(METRIC, X, Y), MapSpec(METRIC, X)],
                                  tmp_path / "figures")
    rows[0]["message"] = "<script>alert(1)</script>"
    path = write_sweep_html(tmp_path, rows, figures, title="Sweep <nn>",
                            summary_lines=["24 runs: 22 completed", "wall time 36 s"])
    assert path == tmp_path / "sweep.html"
    text = path.read_text()
    assert "<script>" not in text and "&lt;script&gt;" in text
    assert "<title>Sweep &lt;nn&gt;</title>" in text
    assert "24 runs: 22 completed" in text and "wall time 36 s" in text
    assert "http://" not in text and "https://" not in text and "src=\"/" not in text

    page = Page()
    page.feed(text)
    assert page.images == [f"figures/{p.name}" for p in figures]
    assert all((tmp_path / src).is_file() for src in page.images)
    assert len(page.rows) == len(rows)
    by_point = {cells[0][1]: cells for cells in page.rows}
    for row in rows:
        cells = by_point[row["point"]]
        assert cells[1] == (f"status-{row['status']}", row["status"])
    # The status classes are coloured: green, orange, red.
    css = text[text.index("<style>"):text.index("</style>")]
    for status in ("completed", "lost_contact", "diverged", "failed"):
        assert f"td.status-{status}" in css


class Page(html.parser.HTMLParser):
    """The images and the table's rows of a page: per row, (class, text) per cell."""

    def __init__(self):
        super().__init__()
        self.images, self.rows, self._cell = [], [], None

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag == "img":
            self.images.append(attrs["src"])
        elif tag == "tr":
            self.rows.append([])
        elif tag == "td":
            self._cell = [attrs.get("class"), ""]

    def handle_data(self, data):
        if self._cell is not None:
            self._cell[1] += data

    def handle_endtag(self, tag):
        if tag == "td":
            self.rows[-1].append(tuple(self._cell))
            self._cell = None
        elif tag == "thead":
            self.rows.pop()  # the header row
