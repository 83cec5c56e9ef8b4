"""Figures and the HTML report of a parameter sweep.

A sweep runs a scenario at every point of a grid of scenario fields, once per
seed, and records one row per run (``DIR/results.csv``): the run folder's name
``point``, one column per varied field named by its dotted scenario path
(``environment.stiffness``), ``seed``, ``status`` (``completed``,
``lost_contact``, ``diverged``, ``failed``, ``interrupted``), ``message``,
``wall_time_s`` and the run's scalar metrics flattened with dots
(``force_rmse_n``, ``identification_error_rls_matched.stiffness``). This
module answers the sweep's question, *where does the scheme work and where
does it go unstable*:

- :func:`aggregate` reduces the rows over seeds (and over any field not
  grouped by): mean, std, min, max, number of finite values, and how many runs
  diverged, lost contact or failed.
- :func:`plot_heat_map` and :func:`plot_metric_line` draw one metric over one
  or two fields on Axes the caller owns and return what they drew; cells or
  points where any run diverged, failed or lost contact carry a cross.
- :func:`plot_sweep_map` draws one map spec on a figure (facets as small
  multiples); :func:`write_sweep_figures` writes one PNG per map spec, and
  :func:`write_sweep_html` a self-contained ``sweep.html`` (the figures and
  the table of every run; no external resources).

Rows may come straight from the runner (floats, ints, bools, None) or from
``csv.DictReader`` on ``results.csv`` (every value a string, missing values
empty): values are normalized the same way, so both give the same figures.
Field values sort numerically (``"1e3"`` < ``"2e4"``); non-numeric
(categorical) values sort after the numbers, alphabetically.

Like :mod:`drake_contact.app.plotting`, nothing here uses pyplot: the helpers
draw on given Axes, and the writers draw on ``matplotlib.figure.Figure``
objects, so no backend is chosen or needed.
"""

import dataclasses as dc
import html
import math
import os
import re
from collections.abc import Mapping
from pathlib import Path

import matplotlib
import numpy as np
from matplotlib.collections import QuadMesh
from matplotlib.figure import Figure
from matplotlib import patheffects
from matplotlib.lines import Line2D

__all__ = [
    "STATUSES", "HeatMap", "aggregate", "plot_heat_map", "plot_metric_line",
    "plot_sweep_map", "write_sweep_figures", "write_sweep_html", "markdown_map",
]

#: Every status a sweep row can have, in the order the report counts them.
STATUSES = ("completed", "lost_contact", "diverged", "failed", "interrupted")
#: Statuses whose cells and points are crossed in red.
_UNSTABLE = ("diverged", "failed")
#: Colours of the crosses: diverged or failed, lost contact.
_RED, _ORANGE = "#d62728", "#ff7f0e"
#: Columns every row has that are neither varied fields nor metrics.
_BOOKKEEPING = {"point", "seed", "status", "message", "wall_time_s"}
#: A dark outline around the crosses, so an orange cross reads on an orange line.
_OUTLINE = [patheffects.Stroke(linewidth=4, foreground="black"), patheffects.Normal()]
#: A field is drawn on a log axis by default when its values are all positive
#: and span more than this factor.
_LOG_SPAN = 20.0


# --------------------------------------------------------------- values


def _field_value(value):
    """One varied field's value, the same whether it came from the runner or
    from the CSV: a float for numbers, a bool for booleans, else the string;
    None when missing."""
    if value is None or isinstance(value, bool):
        return value
    if isinstance(value, (int, float, np.integer, np.floating)):
        return float(value)
    text = str(value).strip()
    if text == "":
        return None
    if text.lower() in ("true", "false"):
        return text.lower() == "true"
    try:
        return float(text)
    except ValueError:
        return text


def _metric_value(value) -> float:
    """A metric as a float: booleans are 0/1; None, empty and non-numeric
    strings are NaN."""
    value = _field_value(value)
    if isinstance(value, bool):
        return float(value)
    if isinstance(value, float):
        return value
    return math.nan


def _sort_key(value):
    """Numbers (and booleans) first, numerically; then strings; None last."""
    if value is None:
        return (2, 0.0, "")
    if isinstance(value, (bool, float)):
        return (0, float(value), "")
    return (1, 0.0, str(value))


#: Units the varied fields read in, on axes and in tables: field ->
#: (divisor, unit). Other fields show their values as they are.
FIELD_UNITS = {
    "environment.stiffness": (1e3, "kN/m"),
    "environment.damping": (1.0, "N s/m"),
    "environment.mass": (1.0, "kg"),
    "environment.friction_coefficient": (1.0, ""),
    "simulation.duration": (1.0, "s"),
    "force_sensor.noise_std_n": (1.0, "N"),
}


def field_label(field: str) -> str:
    """A varied field's name with its unit, e.g. ``environment.stiffness (kN/m)``."""
    unit = FIELD_UNITS.get(field, (1.0, ""))[1]
    return f"{field} ({unit})" if unit else field


def _value_with_unit(value, field) -> str:
    """``field = value unit``, e.g. ``environment.damping = 10 N s/m``."""
    unit = FIELD_UNITS.get(field, (1.0, ""))[1] if isinstance(value, float) else ""
    return f"{field} = {_format_value(value, field)}" + (f" {unit}" if unit else "")


def _format_value(value, field="") -> str:
    """A value in its field's unit (:data:`FIELD_UNITS`): 7000 N/m reads 7,
    with the unit in the axis label; four significant digits, and no
    exponent from 0.001 to a million."""
    if not isinstance(value, float):
        return str(value)
    value /= FIELD_UNITS.get(field, (1.0, ""))[0]
    text = "%.4g" % value
    if "e" in text and 1e-3 <= abs(value) < 1e6:
        text = "%.0f" % value
    return text


def _is_numeric(values) -> bool:
    return all(isinstance(v, float) and math.isfinite(v) for v in values)


def _auto_log(values) -> bool:
    """True when ``values`` are all positive numbers spanning more than a
    factor :data:`_LOG_SPAN`."""
    values = [v for v in values if v is not None]
    if not values or not _is_numeric(values) or min(values) <= 0:
        return False
    return max(values) / min(values) > _LOG_SPAN


def _select(rows, where):
    """The rows whose fields equal ``where``'s values (all rows for None)."""
    if not where:
        return list(rows)
    wanted = {field: _field_value(value) for field, value in where.items()}
    return [row for row in rows
            if all(_field_value(row.get(field)) == value for field, value in wanted.items())]


def _as_list(fields) -> list[str]:
    if fields is None:
        return []
    if isinstance(fields, str):
        return [fields]
    return list(fields)


def _field_values(rows, field) -> list:
    """The sorted distinct values ``field`` takes in ``rows``."""
    return sorted({_field_value(row.get(field)) for row in rows}, key=_sort_key)


# ------------------------------------------------------------ aggregate


def aggregate(rows, by, metric) -> dict:
    """Reduce a metric over seeds, per combination of the ``by`` fields.

    Parameters
    ----------
    rows : sequence of mapping
        The sweep's rows (the runner's dicts, or ``csv.DictReader`` rows of
        ``results.csv``).
    by : list of str, or str
        The fields to group by (dotted scenario paths). Rows that differ only
        in other columns (the seed, and any varied field not listed) are
        pooled in one group.
    metric : str
        The metric's column. Booleans count as 0/1; None, empty, NaN and
        infinite values are left out of the statistics (but the run still
        counts in ``n_runs`` and the status counts), and so are the values
        of diverged or failed runs (their metrics describe a truncated log).

    Returns
    -------
    dict
        Keyed by the tuple of the ``by`` fields' values (one entry per field,
        in ``by``'s order; numbers as float), in sorted order (numerically,
        field by field). Each value is a dict with:

        - ``mean``, ``std``, ``min``, ``max`` : float -- over the finite
          values; NaN when there are none. ``std`` is the sample standard
          deviation (ddof=1), NaN with fewer than two values.
        - ``count`` : int -- number of finite values.
        - ``n_runs`` : int -- number of rows in the group.
        - ``n_completed``, ``n_lost_contact``, ``n_diverged``, ``n_failed``,
          ``n_interrupted`` : int -- rows per status.
    """
    by = _as_list(by)
    groups: dict[tuple, list] = {}
    for row in rows:
        key = tuple(_field_value(row.get(field)) for field in by)
        groups.setdefault(key, []).append(row)
    result = {}
    for key in sorted(groups, key=lambda k: tuple(_sort_key(v) for v in k)):
        group = groups[key]
        # A diverged or failed run's metrics are of a truncated log: they
        # are left out of the statistics (the cell is crossed instead).
        values = np.array([math.nan if str(row.get("status")) in _UNSTABLE
                           else _metric_value(row.get(metric)) for row in group], dtype=float)
        finite = values[np.isfinite(values)]
        n = finite.size
        stats = {
            "mean": float(finite.mean()) if n else math.nan,
            "std": float(finite.std(ddof=1)) if n > 1 else math.nan,
            "min": float(finite.min()) if n else math.nan,
            "max": float(finite.max()) if n else math.nan,
            "count": int(n),
            "n_runs": len(group),
        }
        statuses = [str(row.get("status") or "") for row in group]
        for status in STATUSES:
            stats[f"n_{status}"] = statuses.count(status)
        result[key] = stats
    return result


def _n_unstable(stats) -> int:
    return sum(stats[f"n_{status}"] for status in _UNSTABLE)


# ------------------------------------------------------------- heat map


@dc.dataclass
class HeatMap:
    """What :func:`plot_heat_map` drew and the numbers behind it; arrays are
    indexed ``[y, x]`` in the order of ``y_values`` and ``x_values``."""

    # The coloured cells.
    image: QuadMesh
    # Mean of the metric over seeds per cell; NaN where no finite value.
    values: np.ndarray
    # The x field's sorted values (floats for numbers), one per column.
    x_values: list
    # The y field's sorted values, one per row.
    y_values: list
    # Cells where any run diverged, failed or lost contact.
    marked: np.ndarray
    # Sample std over seeds per cell (NaN with fewer than two finite values).
    std: np.ndarray = None
    # Number of finite metric values per cell.
    count: np.ndarray = None
    # Cells where any run diverged or failed (red cross).
    unstable: np.ndarray = None
    # Cells where any run lost contact and none diverged or failed (orange).
    lost_contact: np.ndarray = None
    # The crosses drawn (one Line2D per colour used).
    crosses: list = dc.field(default_factory=list)
    # The per-cell annotations, ``texts[i][j]`` for cell (y_values[i], x_values[j]).
    texts: list = dc.field(default_factory=list)
    # The colorbar, labelled with the metric.
    colorbar: object = None


def _axis_layout(values, log):
    """Positions of the cells' centres and their edges along one axis.

    Numbers sit at their values, the edges halfway between neighbours
    (geometrically on a log axis); categories sit at 0, 1, 2, ...
    """
    if not _is_numeric(values):
        centres = np.arange(len(values), dtype=float)
        return centres, np.arange(len(values) + 1, dtype=float) - 0.5
    centres = np.array(values, dtype=float)
    if log:
        logs = np.log10(centres)
        return centres, 10.0 ** _edges(logs, half_width=0.5)
    return centres, _edges(centres, half_width=0.5 * max(abs(centres[0]), 1.0))


def _edges(centres, *, half_width):
    """Cell edges around sorted centres: midpoints inside, the outer cells as
    wide as their neighbours (``half_width`` on both sides for one cell)."""
    if centres.size == 1:
        return np.array([centres[0] - half_width, centres[0] + half_width])
    mid = 0.5 * (centres[1:] + centres[:-1])
    return np.concatenate([[2 * centres[0] - mid[0]], mid, [2 * centres[-1] - mid[-1]]])


def _set_axis(ax, which, field, values, centres, edges, log):
    axis = ax.xaxis if which == "x" else ax.yaxis
    if log:
        (ax.set_xscale if which == "x" else ax.set_yscale)("log")
    (ax.set_xlim if which == "x" else ax.set_ylim)(edges[0], edges[-1])
    axis.set_ticks(centres, labels=[_format_value(v, field) for v in values])
    axis.set_ticks([], minor=True)
    (ax.set_xlabel if which == "x" else ax.set_ylabel)(field_label(field))


def _text_colour(image, value) -> str:
    """Black or white, whichever reads better on the cell's colour."""
    r, g, b, _ = image.cmap(image.norm(value))
    return "black" if 0.299 * r + 0.587 * g + 0.114 * b > 0.5 else "white"


def _cell_label(stats) -> str:
    if stats["count"] == 0:
        return "n/a"
    text = "%.3g" % stats["mean"]
    if stats["count"] > 1:
        text += "\n±%.2g" % stats["std"]
    return text


def plot_heat_map(ax, rows, metric, x, y, *, log_x=None, log_y=None, where=None,
                  cmap="viridis", norm=None, annotate=True) -> HeatMap:
    """Draw a metric's mean over seeds on the grid of two varied fields.

    One cell per grid point, coloured by the mean of ``metric`` over the
    runs at that point (seeds, and any varied field other than ``x``, ``y``
    and ``where``'s). Each cell is annotated with the mean (and ``±`` the
    sample std when more than one seed gave a finite value). Cells where any
    run diverged or failed carry a red cross, where any run lost contact an
    orange one; cells without a finite value are left blank ("n/a").

    Parameters
    ----------
    ax : matplotlib.axes.Axes
        Axes to draw on; its figure gets the colorbar.
    rows : sequence of mapping
        The sweep's rows (see :func:`aggregate`).
    metric : str
        The metric's column, the colour.
    x, y : str
        The varied fields along the horizontal and vertical axes.
    log_x, log_y : bool, optional
        Log axes. Default (None): log when the field's values are all
        positive and span more than a factor 20.
    where : mapping of str to value, optional
        Draw only the rows whose fields have these values (one facet).
    cmap : str or matplotlib.colors.Colormap, optional
        Colour map of the cells.
    norm : matplotlib.colors.Normalize, optional
        Colour normalization (e.g. ``LogNorm()`` for a metric spanning
        decades); default linear over the finite means.
    annotate : bool, optional
        Write the mean (±std) in each cell.

    Returns
    -------
    HeatMap
        The mesh, the means and masks per cell, the crosses, texts and
        colorbar.
    """
    rows = _select(rows, where)
    stats = aggregate(rows, [y, x], metric)
    x_values, y_values = _field_values(rows, x), _field_values(rows, y)
    log_x = _auto_log(x_values) if log_x is None else log_x
    log_y = _auto_log(y_values) if log_y is None else log_y
    shape = (len(y_values), len(x_values))
    values, std = np.full(shape, np.nan), np.full(shape, np.nan)
    count = np.zeros(shape, dtype=int)
    unstable, lost = np.zeros(shape, dtype=bool), np.zeros(shape, dtype=bool)
    for i, y_value in enumerate(y_values):
        for j, x_value in enumerate(x_values):
            cell = stats.get((y_value, x_value))
            if cell is None:
                continue
            values[i, j], std[i, j], count[i, j] = cell["mean"], cell["std"], cell["count"]
            unstable[i, j] = _n_unstable(cell) > 0
            lost[i, j] = cell["n_lost_contact"] > 0 and not unstable[i, j]

    x_centres, x_edges = _axis_layout(x_values, log_x)
    y_centres, y_edges = _axis_layout(y_values, log_y)
    cmap = (matplotlib.colormaps[cmap] if isinstance(cmap, str) else cmap)
    image = ax.pcolormesh(x_edges, y_edges, np.ma.masked_invalid(values),
                          cmap=cmap.with_extremes(bad="#eeeeee"), norm=norm, shading="flat")
    _set_axis(ax, "x", x, x_values, x_centres, x_edges, log_x)
    _set_axis(ax, "y", y, y_values, y_centres, y_edges, log_y)
    colorbar = ax.figure.colorbar(image, ax=ax, label=metric)

    # Crosses spanning most of a cell (as the axes are before any layout).
    box = ax.get_position()
    width, height = ax.figure.get_size_inches() * 72 * (box.width, box.height)
    size = max(10.0, 0.6 * min(width / len(x_values), height / len(y_values)))
    crosses = []
    for mask, colour, label in ((unstable, _RED, "diverged or failed (any seed)"),
                                (lost, _ORANGE, "lost contact (any seed)")):
        i, j = np.nonzero(mask)
        if i.size:
            crosses += ax.plot(x_centres[j], y_centres[i], linestyle="none", marker="x",
                               markersize=size, markeredgewidth=2.5, color=colour,
                               label=label, zorder=3, path_effects=_OUTLINE)
    texts = []
    heat_marked = unstable | lost
    if annotate:
        for i, y_value in enumerate(y_values):
            texts.append([])
            for j, x_value in enumerate(x_values):
                cell = stats.get((y_value, x_value))
                if cell is None:
                    texts[-1].append(None)
                    continue
                # On a crossed cell the text sits on a pale box, above the cross.
                box = dict(boxstyle="round,pad=0.2", facecolor="white", alpha=0.8,
                           linewidth=0) if heat_marked[i, j] else None
                colour = ("black" if cell["count"] == 0 or box
                          else _text_colour(image, values[i, j]))
                texts[-1].append(ax.text(x_centres[j], y_centres[i], _cell_label(cell),
                                         ha="center", va="center", fontsize=7,
                                         color=colour, bbox=box, zorder=4))
    if crosses:
        ax.legend(handles=crosses, loc="upper center", bbox_to_anchor=(0.5, -0.2),
                  ncols=len(crosses), fontsize=7, frameon=False, markerscale=9.0 / size)
    return HeatMap(image=image, values=values, x_values=x_values, y_values=y_values,
                   marked=heat_marked, std=std, count=count, unstable=unstable,
                   lost_contact=lost, crosses=crosses, texts=texts, colorbar=colorbar)


# ------------------------------------------------------------ line plot


def _group_label(fields, key) -> str:
    return ", ".join(_value_with_unit(value, field) for field, value in zip(fields, key))


def plot_metric_line(ax, rows, metric, x, *, group=None, log_x=None, where=None,
                     spread="minmax") -> list[Line2D]:
    """Draw a metric's mean over seeds against one varied field.

    One line per value of ``group`` (all rows pooled when None), with a
    shaded band over seeds: min to max, or mean ± sample std. The legend says
    which. Points where any run diverged or failed carry a red cross, where
    any run lost contact an orange one; a point without a finite value gets
    its cross at the bottom of the axes.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
        Axes to draw on.
    rows : sequence of mapping
        The sweep's rows (see :func:`aggregate`).
    metric : str
        The metric's column, on the vertical axis.
    x : str
        The varied field on the horizontal axis. Non-numeric values are
        placed at 0, 1, 2, ... and labelled.
    group : str or list of str, optional
        The field(s) whose values get a line each; runs differing in any
        other field (seeds included) are pooled in a point.
    log_x : bool, optional
        Log horizontal axis. Default (None): log when x's values are all
        positive and span more than a factor 20.
    where : mapping of str to value, optional
        Draw only the rows whose fields have these values (one facet).
    spread : {"minmax", "std"}, optional
        The band: min to max over seeds, or mean ± std.

    Returns
    -------
    list of matplotlib.lines.Line2D
        The mean lines, one per group value in sorted order; ``get_xdata()``
        are x's values (positions for categories), ``get_ydata()`` the means.
    """
    if spread not in ("minmax", "std"):
        raise ValueError(f"spread = {spread!r}: expected 'minmax' or 'std'")
    rows = _select(rows, where)
    group = _as_list(group)
    x_values = _field_values(rows, x)
    log_x = _auto_log(x_values) if log_x is None else log_x
    numeric = _is_numeric(x_values)
    positions = {value: (value if numeric else float(k)) for k, value in enumerate(x_values)}
    stats = aggregate(rows, group + [x], metric)
    keys = sorted({key[:-1] for key in stats}, key=lambda k: tuple(_sort_key(v) for v in k))
    bottom = ax.get_xaxis_transform()

    lines = []
    crossed = {_RED: [], _ORANGE: []}
    for key in keys:
        points = [(k[-1], s) for k, s in stats.items() if k[:-1] == key]
        xs = np.array([positions[value] for value, _ in points])
        mean = np.array([s["mean"] for _, s in points])
        if spread == "minmax":
            low, high = np.array([s["min"] for _, s in points]), np.array([s["max"] for _, s in points])
        else:
            std = np.nan_to_num(np.array([s["std"] for _, s in points]))
            low, high = mean - std, mean + std
        label = _group_label(group, key) if group else "mean over seeds"
        (line,) = ax.plot(xs, mean, marker="o", markersize=4, label=label)
        ax.fill_between(xs, low, high, color=line.get_color(), alpha=0.2, linewidth=0)
        lines.append(line)
        for position, y, (_, s) in zip(xs, mean, points):
            colour = _RED if _n_unstable(s) else _ORANGE if s["n_lost_contact"] else None
            if colour:
                crossed[colour].append((position, y))

    # The band's legend entry, grey, once for all lines.
    band = "min–max over seeds" if spread == "minmax" else "±1 std over seeds"
    ax.fill_between([], [], [], color="0.5", alpha=0.3, linewidth=0, label=f"band: {band}")
    for colour, label in ((_RED, "diverged or failed (any seed)"),
                          (_ORANGE, "lost contact (any seed)")):
        finite = [(p, y) for p, y in crossed[colour] if np.isfinite(y)]
        missing = [p for p, y in crossed[colour] if not np.isfinite(y)]
        style = dict(linestyle="none", marker="x", markersize=9, markeredgewidth=2,
                     color=colour, zorder=4, path_effects=_OUTLINE)
        if finite:
            ax.plot(*zip(*finite), label=label, **style)
        if missing:
            ax.plot(missing, [0.03] * len(missing), transform=bottom,
                    label=None if finite else label, **style)
    if log_x:
        ax.set_xscale("log")
    if not numeric or len(x_values) <= 8:
        ax.set_xticks([positions[v] for v in x_values],
                      labels=[_format_value(v, x) for v in x_values])
        ax.set_xticks([], minor=True)
    ax.set_xlabel(field_label(x))
    ax.set_ylabel(metric)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(loc="best", fontsize=7)
    return lines


# -------------------------------------------------------------- writers


def _spec(spec, name, default=None):
    """A map spec's field, from a dataclass or a dict."""
    if isinstance(spec, Mapping):
        return spec.get(name, default)
    return getattr(spec, name, default)


def _file_name(metric, x, y, facet) -> str:
    parts = [metric, x] + ([y] if y else [])
    name = "map_" + "_".join(parts) + (f"_by_{facet}" if facet else "")
    return re.sub(r"[^A-Za-z0-9_-]", "_", name) + ".png"


def _varied_fields(rows) -> list[str]:
    """Columns that are scenario fields: their first dotted component is a
    field of :class:`drake_contact.scenario.Scenario`."""
    from drake_contact.scenario import Scenario

    sections = {field.name for field in dc.fields(Scenario)}
    columns = dict.fromkeys(key for row in rows for key in row)
    return [c for c in columns if c not in _BOOKKEEPING and c.split(".")[0] in sections]


def plot_sweep_map(fig, rows, spec, *, varied=None) -> list:
    """Draw one map spec on a figure: one panel per facet value.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        An empty figure; the panels are added to it (up to three per row).
    rows : sequence of mapping
        The sweep's rows (see :func:`aggregate`).
    spec : dataclass or dict
        The map: ``metric`` (a column), ``x`` (a varied field), and
        optionally ``y`` (a varied field: a heat map, :func:`plot_heat_map`;
        absent, a line plot, :func:`plot_metric_line`, one line per value of
        the varied fields other than ``x`` and ``facet``), ``facet`` (a
        varied field: one panel per value), ``title``, ``log_x`` and
        ``log_y`` (None or absent: log when the field's values are all
        positive and span more than a factor 20).
    varied : list of str, optional
        The sweep's varied fields, for the line plots' groups and the note of
        what a heat map pools. Default: the columns whose first dotted
        component is a section of the scenario (``environment.stiffness``).

    Returns
    -------
    list
        Per panel, in the facet's sorted order (one panel without a facet):
        the :class:`HeatMap`, or the list of mean lines of a line plot.
    """
    rows = list(rows)
    varied = _varied_fields(rows) if varied is None else list(varied)
    metric, x, y, facet = (_spec(spec, k) for k in ("metric", "x", "y", "facet"))
    log_x, log_y = _spec(spec, "log_x"), _spec(spec, "log_y")
    facet_values = _field_values(rows, facet) if facet else [None]
    n = len(facet_values)
    ncols = min(n, 3)
    axes = np.ravel(fig.subplots(math.ceil(n / ncols), ncols, squeeze=False))
    # Fields neither on an axis nor a facet: lines of a line plot, pooled in a heat map.
    others = [f for f in varied if f not in (x, y, facet)]
    panels = []
    # One colour scale for every panel, so facets compare at a glance.
    means = [stats["mean"] for stats in aggregate(rows, [f for f in (facet, x, y) if f],
                                                  metric).values()
             if math.isfinite(stats["mean"])] if y else []
    norm = matplotlib.colors.Normalize(min(means), max(means)) if means else None
    for ax, value in zip(axes, facet_values):
        where = {facet: value} if facet else None
        if y:
            panels.append(plot_heat_map(ax, rows, metric, x, y, log_x=log_x, log_y=log_y,
                                        where=where, norm=norm))
        else:
            if log_y is None:
                log_y = _auto_log([v for v in (_metric_value(r.get(metric)) for r in rows)
                                   if math.isfinite(v)])
            panels.append(plot_metric_line(ax, rows, metric, x, group=others or None,
                                           log_x=log_x, where=where))
            if log_y:
                ax.set_yscale("log")
        if facet:
            ax.set_title(_value_with_unit(value, facet), fontsize=10)
    for ax in axes[n:]:
        fig.delaxes(ax)
    title = _spec(spec, "title") or (f"{metric} over {x} × {y}" if y else f"{metric} vs {x}")
    if y:
        title += f"\n(mean over seeds{''.join(', ' + f for f in others)})"
    fig.suptitle(title, fontsize=11)
    return panels


def write_sweep_figures(rows, maps, out_dir, *, varied=None) -> list[Path]:
    """Write one PNG per map spec (:func:`plot_sweep_map`).

    Parameters
    ----------
    rows : sequence of mapping
        The sweep's rows (see :func:`aggregate`).
    maps : sequence of dataclass or dict
        Map specs (see :func:`plot_sweep_map`).
    out_dir : str or pathlib.Path
        Directory for the PNGs (created if missing).
    varied : list of str, optional
        The sweep's varied fields (see :func:`plot_sweep_map`).

    Returns
    -------
    list of pathlib.Path
        The files, in ``maps``' order, named
        ``map_<metric>_<x>[_<y>][_by_<facet>].png`` with every character
        other than letters, digits, ``-`` and ``_`` (dots) replaced by ``_``;
        a name already written in this call gets a ``_2``, ``_3``, ... suffix.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = list(rows)
    varied = _varied_fields(rows) if varied is None else list(varied)
    paths = []
    for spec in maps:
        facet = _spec(spec, "facet")
        n = len(_field_values(rows, facet)) if facet else 1
        ncols = min(n, 3)
        height = 4.6 if _spec(spec, "y") else 4.0
        fig = Figure(figsize=(6.0 * ncols, height * math.ceil(n / ncols) + 0.5),
                     layout="constrained")
        plot_sweep_map(fig, rows, spec, varied=varied)
        name = _file_name(*(_spec(spec, k) for k in ("metric", "x", "y", "facet")))
        path, k = out_dir / name, 1
        while path in paths:
            k += 1
            path = out_dir / name.replace(".png", f"_{k}.png")
        fig.savefig(path, dpi=110)
        paths.append(path)
    return paths


_CSS = """
body { font-family: sans-serif; margin: 1.5em; color: #222; }
h1 { font-size: 1.4em; }
ul.summary { line-height: 1.5; }
figure { display: inline-block; margin: 0.5em; vertical-align: top; }
figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption { font-size: 0.8em; color: #555; }
table { border-collapse: collapse; font-size: 0.8em; }
th, td { border: 1px solid #ccc; padding: 2px 6px; text-align: right; white-space: nowrap; }
th { background: #f0f0f0; position: sticky; top: 0; }
td.text { text-align: left; white-space: normal; }
td.status-completed { background: #c8e6c9; }
td.status-lost_contact { background: #ffe0b2; }
td.status-diverged, td.status-failed { background: #ffcdd2; }
td.status-interrupted { background: #e0e0e0; }
"""


def _cell_text(value) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return "%.6g" % value
    return str(value)


def _status_class(status) -> str:
    return "status-" + re.sub(r"[^A-Za-z0-9_-]", "_", str(status or "unknown"))


def write_sweep_html(out_dir, rows, figures, *, title, summary_lines=()) -> Path:
    """Write ``out_dir/sweep.html``: the sweep's report, readable offline.

    Parameters
    ----------
    out_dir : str or pathlib.Path
        The sweep's directory (created if missing).
    rows : sequence of mapping
        The sweep's rows; the table has one line per row and one column per
        key (in order of first appearance, ``point`` and ``status`` first).
        The status cell has the class ``status-<status>``: green for
        completed, orange for lost_contact, red for diverged and failed.
    figures : sequence of str or pathlib.Path
        PNGs to embed (e.g. :func:`write_sweep_figures`' files), referenced
        by paths relative to ``out_dir``.
    title : str
        The page's title and heading.
    summary_lines : sequence of str, optional
        Lines listed under the heading (points done and failed, wall time,
        overhead).

    Returns
    -------
    pathlib.Path
        The file written. Every text is HTML-escaped; the page loads no
        external resource (styles inline, images local).
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    esc = html.escape
    rows = list(rows)
    columns = list(dict.fromkeys(["point", "status"] + [k for row in rows for k in row]))
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{esc(title)}</title>",
        f"<style>{_CSS}</style>",
        "</head><body>",
        f"<h1>{esc(title)}</h1>",
    ]
    if summary_lines:
        parts.append('<ul class="summary">')
        parts += [f"<li>{esc(str(line))}</li>" for line in summary_lines]
        parts.append("</ul>")
    if figures:
        parts.append("<h2>Maps</h2>")
    for figure in figures:
        source = Path(os.path.relpath(Path(figure).resolve(), out_dir.resolve())).as_posix()
        parts.append(f'<figure><img src="{esc(source)}" alt="{esc(Path(figure).name)}">'
                     f"<figcaption>{esc(Path(figure).name)}</figcaption></figure>")
    parts.append(f"<h2>Runs ({len(rows)})</h2>")
    parts.append("<table><thead><tr>"
                 + "".join(f"<th>{esc(c)}</th>" for c in columns) + "</tr></thead><tbody>")
    for row in rows:
        cells = []
        for column in columns:
            value = row.get(column)
            if column == "status":
                css = _status_class(value)
            elif isinstance(value, str) and _field_value(value).__class__ is str:
                css = "text"
            else:
                css = None
            attribute = f' class="{esc(css)}"' if css else ""
            cells.append(f"<td{attribute}>{esc(_cell_text(value))}</td>")
        parts.append("<tr>" + "".join(cells) + "</tr>")
    parts += ["</tbody></table>", "</body></html>", ""]
    path = out_dir / "sweep.html"
    path.write_text("\n".join(parts), encoding="utf-8")
    return path


def markdown_map(rows, metric, x, y, *, facet="", title="") -> str:
    """A heat map as Markdown tables (one per ``facet`` value): ``y`` down,
    ``x`` across, each cell the mean over seeds and, where runs went wrong,
    how many of them lost contact, diverged or failed (e.g. ``2.31, lost
    1/3``). A map with no ``y`` (a line plot) is a table with ``x`` down:
    the mean over seeds, its range and the runs that went wrong. For READMEs,
    notes and the documentation's snapshots."""
    facets = _field_values(rows, facet) if facet else [None]
    x_values = _field_values(rows, x)
    if not y:
        out = [f"**{title or metric}** (over seeds; {x} down)", ""]
        for value in facets:
            where = {facet: value} if facet else None
            stats = aggregate(_select(rows, where), [x], metric)
            if facet:
                out += [f"{_value_with_unit(value, facet)}:", ""]
            out += [f"| {field_label(x)} | mean | min-max | runs |", "|---|---|---|---|"]
            for xv in x_values:
                cell = stats.get((_field_value(xv),))
                spread = ("" if cell is None or cell["count"] == 0 else
                          "%.3g to %.3g" % (cell["min"], cell["max"]))
                runs = "" if cell is None else str(cell["n_runs"])
                out.append(f"| {_format_value(xv, x)} | {_markdown_cell(cell)} | {spread} | "
                           f"{runs} |")
            out.append("")
        return "\n".join(out)
    y_values = _field_values(rows, y)
    out = [f"**{title or metric}** (mean over seeds; {y} down, {x} across)", ""]
    for value in facets:
        where = {facet: value} if facet else None
        stats = aggregate(_select(rows, where), [y, x], metric)
        if facet:
            out.append(f"{_value_with_unit(value, facet)}:")
            out.append("")
        out.append("| " + " | ".join([f"{field_label(y)} \\ {field_label(x)}"]
                                     + [_format_value(v, x) for v in x_values])
                   + " |")
        out.append("|" + "---|" * (len(x_values) + 1))
        for yv in y_values:
            cells = []
            for xv in x_values:
                cell = stats.get((_field_value(yv), _field_value(xv)))
                cells.append(_markdown_cell(cell))
            out.append("| " + " | ".join([_format_value(yv, y)] + cells) + " |")
        out.append("")
    return "\n".join(out)


def _markdown_cell(stats) -> str:
    if stats is None:
        return ""
    text = "n/a" if stats["count"] == 0 else "%.3g" % stats["mean"]
    bad = [f"{name} {stats[f'n_{status}']}/{stats['n_runs']}"
           for status, name in (("lost_contact", "lost"), ("diverged", "diverged"),
                                ("failed", "failed")) if stats[f"n_{status}"]]
    return ", ".join([text] + bad)
