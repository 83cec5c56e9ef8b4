"""One command reproduces the thesis: every bundled thesis scenario, its
figures, a scored report and a browser playback per material.

    drake-contact reproduce [--quick] --out DIR [--jobs N] [--seeds 0-2]

Each scenario runs once per seed (default seeds 0, 1 and 2) as a point of a
campaign (:mod:`drake_contact.app.campaign`) on ``--jobs`` local Dask workers
(default one per core), as ``drake-contact run`` would run it, writing
``DIR/<scenario>/seed_<s>/`` (logs, metrics, figures, ``run.log``);
the identification runs of the first seed also record a Meshcat playback
(``playback.html``). Then :data:`RESULTS`, the thesis's results (chapter 6),
are scored from the runs' ``metrics.json``, seed by seed: each result is a
set of :class:`Bound` s on measured numbers, and a row is reproduced only
when every seed meets every bound with the bound's margin (long runs are
chaotic at rounding level, so a seed that sits on a threshold would flip
between machines). Each row shows the thesis's claim, what we measured (the
first seed's numbers and the spread over the seeds), the ground truth, the
bounds, and whether that matches what we expect: a result the faithful model
does not reproduce is a documented deviation (:attr:`Result.deviation`,
with its measured cause). ``DIR/report.md`` and ``DIR/report.html`` show the
rows with the first seed's figures embedded: the rows' figures first, then
every other figure that seed's runs wrote, by run. After the rows and the
deviations, the report draws the ``nn_styrofoam`` diagram
(``DIR/diagram.svg`` when Graphviz's ``dot`` is installed; otherwise a link
to its DOT text, ``DIR/diagram.dot``).

The command exits 0 when every row is as expected (reproduced, or a
documented deviation that still deviates) and 1 when one is not: a result
that stops reproducing, or a documented deviation that now passes (as
pytest's strict xfail does: the documentation must then change).

``--quick`` shortens the long runs (:attr:`Job.quick_duration_s`) and skips
the neural runs' hybrid-only baselines; every row is still scored, against
:attr:`Result.expected_quick` where a short run cannot show what the full
one does. Ctrl-C interrupts the running scenarios (each writes its logs up
to then) and still writes the report, with the rows it could not score
marked "not run".
"""

import dataclasses as dc
import html
import json
import math
import re
import time
from collections.abc import Callable
from pathlib import Path, PurePosixPath

from drake_contact.app import claims as thesis_claims
from drake_contact.app.campaign import (
    DEFAULT_ENSEMBLE, Campaign, Point, failure_message, run_campaign)
from drake_contact.constants import RATIO_TOLERANCE


@dc.dataclass
class Job:
    """One scenario of the reproduction."""

    scenario: str
    # Simulated time in --quick (s); None = the scenario's own.
    quick_duration_s: float | None = None
    # Record a Meshcat playback (one per material).
    record: bool = False
    # Run the hybrid-only baseline only to 1 s past the scoring window (no
    # row reads the rest; the figures then draw it that far).
    baseline_window: bool = False


#: The scenarios, longest first so that two cores finish together.
JOBS = [
    # Contact at 8.1 s; adaptation 64-65.5 s after it, so the first 5 s
    # window after it ends by 83.1 s; the first contact loss 77.5 s after
    # contact (85.6 s): 85 s scores the adaptation and the drift before it.
    # Its baseline to the window only: the other 230 s of a hybrid-only run
    # were a quarter of the critical path, and no row reads them.
    Job("nn_small_lr", quick_duration_s=85.0, baseline_window=True),
    Job("nn_styrofoam", quick_duration_s=30.0),
    Job("nn_rubber", quick_duration_s=30.0),
    Job("nn_styrofoam_sine", quick_duration_s=30.0),
    Job("nn_rubber_sine", quick_duration_s=30.0),
    Job("identify_styrofoam", record=True),
    Job("identify_rubber", record=True),
    Job("hybrid_p_only_styrofoam", quick_duration_s=20.0),
    Job("hybrid_p_only_rubber", quick_duration_s=20.0),
    Job("sensor_spectrum"),
]


@dc.dataclass(frozen=True)
class Claim:
    """What the thesis reports for one result: the only copy of its text."""

    experiment: str
    # The thesis's figure numbers, e.g. "6.1-6.3".
    figures: str
    # What the thesis says it shows.
    thesis: str


@dc.dataclass(frozen=True)
class Bound:
    """One numeric criterion of a result, measured on one seed's runs."""

    # What is bounded, with its unit, e.g. "peak force, styrofoam (N)".
    name: str
    # The measured value; None when the event never came (e.g. never
    # settled), which fails the bound.
    value: float | None
    # "<=", ">=" or "==" (a count).
    op: str
    limit: float
    # How far inside the limit every seed must be for the row to be
    # reproduced (same unit; by default 10 % of the limit's scale).
    margin: float = 0.0

    def holds(self, with_margin=False) -> bool:
        if self.value is None or math.isnan(self.value):
            return False
        margin = self.margin if with_margin else 0.0
        if self.op == "<=":
            return self.value <= self.limit - margin
        if self.op == ">=":
            return self.value >= self.limit + margin
        return self.value == self.limit

    def text(self) -> str:
        """The bound as the report states it."""
        return f"{self.name} {self.op} {self.limit:g}" + (
            f" by {self.margin:g}" if self.margin and self.op != "==" else "")


def _within(name, value, low, high, margin):
    """Two bounds: low <= value <= high, each with ``margin``."""
    return [Bound(name, value, ">=", low, margin), Bound(name, value, "<=", high, margin)]


@dc.dataclass
class Score:
    """What we measured for one claim on one seed."""

    measured: str
    truth: str
    # The bounds; empty when the runs are missing.
    bounds: list[Bound] = dc.field(default_factory=list)
    # Figure files (relative to the report) that show it.
    images: list[str] = dc.field(default_factory=list)
    # Why it could not be scored ("not run ...", "not measured ..."), if so.
    problem: str = ""
    # True for "not run" (the runs are missing), False for "not measured".
    missing: bool = False


@dc.dataclass
class Row:
    """One thesis result beside ours over the seeds: a claim's fields, then
    the first seed's measurement, the spread and the verdict."""

    experiment: str
    figures: str
    thesis: str
    measured: str
    truth: str
    tolerance: str
    # True: every seed meets every bound with its margin; False: one does
    # not (``marginal``: every seed meets the bounds, not their margins);
    # None: not run.
    passed: bool | None
    # What we expect: True for a reproduced result, False for a documented
    # deviation (``deviation`` says why).
    expected: bool = True
    deviation: str = ""
    marginal: bool = False
    # Scored on every seed the deviation was documented on (SEEDS): only
    # then does a deviation that passes count as unexpected (a row that
    # fails on one seed of three may pass on that seed's neighbours alone).
    strict: bool = True
    # Figure files (relative to the report) that show it.
    images: list[str] = dc.field(default_factory=list)

    @property
    def as_expected(self) -> bool:
        if self.passed is None:
            return False
        if self.expected:
            return self.passed
        return not self.passed or not self.strict

    def verdict(self) -> str:
        verdict = {True: "PASS", False: "MARGINAL" if self.marginal else "FAIL",
                   None: "not run"}[self.passed]
        if not self.expected and self.passed is not None:
            verdict += (" (documented deviation)" if self.passed is False else
                        " (a documented deviation now passes)" if self.strict else
                        f" (documented deviation over seeds {_seed_list(SEEDS)})")
        return verdict


@dc.dataclass(frozen=True)
class Result:
    """A thesis claim and the scorer that checks it against the runs."""

    claim: Claim
    # Reads one seed's runs' metrics (raising _Missing for a run that did
    # not complete) and returns a Score.
    scorer: Callable[["_Runs"], Score]
    # Reproduced by the full run (True), or a documented deviation whose
    # cause, as measured, is ``deviation``.
    expected: bool = True
    deviation: str = ""
    # The same for --quick, where a short run cannot show what the full one
    # does (None: as the full run).
    expected_quick: bool | None = None

    def expectation(self, quick: bool) -> bool:
        return self.expected if not quick or self.expected_quick is None else self.expected_quick


#: The thesis's results (chapter 6), in its order: each scorer below registers
#: itself with its claim (:func:`_result`), so definition order is report order.
RESULTS: list[Result] = []


def _result(experiment, figures, thesis, **expectation):
    """Registers the decorated scorer in :data:`RESULTS` with its claim (and
    the :class:`Result` fields ``expected``, ``deviation``,
    ``expected_quick``)."""
    claim = Claim(experiment, figures, thesis)

    def register(scorer):
        RESULTS.append(Result(claim, scorer, **expectation))
        return scorer
    return register


#: The seeds a reproduction scores by default.
SEEDS = (0, 1, 2)


class _Missing(Exception):
    """A scenario the row needs did not complete."""


class _Runs:
    """One seed's runs' metrics by scenario name; a missing or unfinished
    run raises _Missing. ``out`` is the report's folder; the runs are in
    ``out/<scenario>/seed_<seed>/``."""

    def __init__(self, out: Path, seed: int):
        self.out = out
        self.seed = seed

    def folder(self, name) -> str:
        return f"{name}/seed_{self.seed}"

    def __getitem__(self, name) -> dict:
        path = self.out / self.folder(name) / "metrics.json"
        if not path.exists():
            raise _Missing(name)
        metrics = json.loads(path.read_text())
        if metrics.get("status") != "completed":
            raise _Missing(name)
        return metrics

    def images(self, name, *stems):
        return [f"{self.folder(name)}/{stem}" for stem in stems
                if (self.out / self.folder(name) / stem).exists()]


def run_metrics(out: Path, name: str, seed: int) -> dict:
    """One completed run's metrics (raising :class:`claims.Missing` otherwise),
    as the claims' scorer reads them."""
    try:
        return _Runs(Path(out), seed)[name]
    except _Missing as missing:
        raise thesis_claims.Missing(f"{missing} did not complete") from None


def score_claims(out_dir, *, seeds=SEEDS, quick=False) -> list[thesis_claims.ClaimRow]:
    """The thesis's claims (:data:`claims.CLAIMS`) scored on the runs in
    ``out_dir`` over ``seeds``."""
    return thesis_claims.score_claims(Path(out_dir), seeds, run_metrics, quick=quick)


def _pct(x):
    return f"{100 * x:+.1f} %"


def _k(x):
    return f"{x / 1e3:.2f} kN/m"


def _time(t):
    return "never" if t is None else f"{t:.3f} s"


@_result("switch from approach to hybrid", "4.2", "force transient at the 5 N switch")
def _switch(runs):
    s, r = runs["identify_styrofoam"], runs["identify_rubber"]
    bounds = []
    for material, m in (("styrofoam", s), ("rubber", r)):
        bounds += [Bound(f"switches, {material}", m["mode_switches"], "==", 1),
                   Bound(f"peak force, {material} (N)", m["impact_peak_force_n"], "<=", 40.0, 4.0)]
    return Score(
        f"{s['mode_switches']} / {r['mode_switches']} switches; peak "
        f"{s['impact_peak_force_n']:.1f} N (styrofoam), {r['impact_peak_force_n']:.1f} N "
        f"(rubber), then 20 N held (mean {s['force_mean_n']:.2f} / {r['force_mean_n']:.2f} N)",
        "f_d = 20 N", bounds, runs.images("identify_styrofoam", "fig4_2_switch.png"))


def _identification_score(runs, material, images, method):
    m = runs[f"identify_{material}"]
    truth = m["true_impedance"]["stiffness"]

    def k(name):
        return m[f"identified_impedance_{name}"]["stiffness"]
    if method == "rls":
        ours, tol_time, tol_rel, time_key = "rls_matched", 0.2, 0.05, "identification_time_rls_matched_s"
    else:
        ours, tol_time, tol_rel, time_key = "nn_offset", 1.0, 0.10, \
            "identification_time_10pct_nn_offset_s"
    settle = m[time_key]
    rel = k(ours) / truth - 1
    measured = (f"{ours} K_e {_k(k(ours))} ({_pct(rel)}), within {int(tol_rel * 100)} % from "
                f"{_time(settle)}; the thesis's form K_e {_k(k(method))}, f / x "
                f"{_k(m['stiffness_ratio_final_n_per_m'])} (both biased by the 5 N switch point)")
    return Score(measured, f"K_e = {_k(truth)}",
                 [Bound(f"|{ours} K_e error| (%)", abs(100 * rel), "<=", 100 * tol_rel,
                        10 * tol_rel),
                  Bound(f"{ours} time to within {int(tol_rel * 100)} % (s)", settle, "<=",
                        tol_time, tol_time / 10)],
                 runs.images(f"identify_{material}", *images))


@_result("RLS, styrofoam", "6.1-6.3",
         "K_e 7.2 k vs f/x 6.8 k (<6 % apart); settles within 0.12 s")
def _rls_styrofoam(runs):
    return _identification_score(
        runs, "styrofoam", ["fig6_1_identification.png", "fig6_3_identification.png"], "rls")


@_result("RLS, rubber", "6.4-6.5", "K_e 44 k = f/x 44 k; settles within 0.05 s")
def _rls_rubber(runs):
    return _identification_score(runs, "rubber", ["fig6_4_identification.png"], "rls")


@_result("NN identification, styrofoam", "6.6-6.8", "K_e 6.6 k vs f/x 6.7 k; about 0.6 s to learn",
         expected=False,
         deviation="nn_offset ends +30 to +31 % (styrofoam) and +19 to +38 % (rubber) high on "
                   "seeds 0-2 on the calibrated walls: its probe sits where the tip rested on "
                   "the old walls (2 mm, 0.3 mm), short of where it rests now (2.9, 0.46 mm). "
                   "Ablation, seeds 0-2, probe at the rest (2.9 and 0.46 mm): styrofoam ends "
                   "-2.6 to -3.9 % (within 10 % from 0.17-0.18 s), rubber -1.0 to -1.2 % (from "
                   "0.074-0.082 s), and both rows pass: the probe is the cause. A probe per wall "
                   "is tuning; the self-scaling nn_auto (identify_any) reads at the operating "
                   "point")
def _nn_styrofoam(runs):
    return _identification_score(
        runs, "styrofoam", ["fig6_7_identification.png", "fig6_6_identification.png",
                            "fig6_8_nn_output_error.png"], "nn")


@_result("NN identification, rubber", "6.9", "K_e 56 k vs f/x 62 k; about 0.6 s",
         expected=False, deviation="nn_offset on rubber: as on styrofoam (the row above), its "
                                   "probe (0.3 mm) sits short of where the tip rests on the "
                                   "calibrated wall (0.46 mm); the row above has the ablation")
def _nn_rubber(runs):
    return _identification_score(runs, "rubber", ["fig6_9_identification.png"], "nn")


def _nn_tracking(runs, names, images):
    parts, bounds = [], []
    for name in names:
        m = runs[name]
        rmse = m["force_rmse_n"]
        adapt = m.get("adaptation_time_s")
        baseline = m.get("baseline_force_rmse_n")
        bounds += [Bound(f"{name} RMSE 10-20 s after contact (N)", rmse, "<=", 1.5, 0.15),
                   Bound(f"{name} adaptation time (s)", adapt, "<=", 10.0, 1.0)]
        parts.append(f"{name}: RMSE {rmse:.2f} N" +
                     (f" (hybrid part alone {baseline:.2f} N)" if baseline is not None else "") +
                     f", adapted in {_time(adapt)}")
    return Score("; ".join(parts), "f_d (true force scored)", bounds,
                 [img for name, stem in zip(names, images) for img in runs.images(name, stem)])


@_result("NN controller, styrofoam / rubber", "6.11, 6.16",
         "follows the 10/20 N square wave about 10 s in", expected=False,
         deviation="nn_styrofoam's RMSE 10-20 s after contact is 1.49 to 1.52 N on seeds 0-2, "
                   "at the 1.5 N bound, and it adapts 18, 15.5 and 18 s after contact; nn_rubber "
                   "meets every bound. Cause not isolated (at 70957cd, on the uncalibrated wall "
                   "and the gauge-dominated noise, 1.37 to 1.40 N and 8 to 10.5 s; at a9a607c, "
                   "on the wall calibrated for that noise, 1.40 to 1.44 N and 8 to 18 s)")
def _nn_square(runs):
    return _nn_tracking(runs, ["nn_styrofoam", "nn_rubber"],
                        ["fig6_11_force_tracking.png", "fig6_16_force_tracking.png"])


@_result("NN controller, + 4 sin(pi t)", "6.12, 6.17", "follows")
def _nn_sine(runs):
    return _nn_tracking(runs, ["nn_styrofoam_sine", "nn_rubber_sine"],
                        ["fig6_12_force_tracking.png", "fig6_17_force_tracking.png"])


def _score_seed(result: Result, runs: _Runs) -> Score:
    try:
        return result.scorer(runs)
    except _Missing as missing:
        return Score("", "", problem=f"not run ({missing} did not complete)", missing=True)
    except KeyError as missing:
        # A run too short for the result (e.g. no scoring window) lacks the metric.
        return Score("", "", problem=f"not measured (metric {missing} missing: run too short?)")


def spread(scores) -> str:
    """Each bound's value over the seeds: ``name a-b`` (one value if equal)."""
    values = {}
    for scored in scores:
        for bound in scored.bounds:
            values.setdefault(bound.name, []).append(bound.value)
    parts = []
    for name, seen in values.items():
        if any(v is None for v in seen):
            parts.append(f"{name} " + ", ".join("never" if v is None else f"{v:.3g}" for v in seen))
        elif min(seen) == max(seen):
            parts.append(f"{name} {min(seen):.3g}")
        else:
            parts.append(f"{name} {min(seen):.3g} to {max(seen):.3g}")
    return "; ".join(parts)


def score(out_dir, *, seeds=SEEDS, quick=False) -> list[Row]:
    """The report's rows from the runs in ``out_dir``, each over ``seeds``;
    a row whose runs are missing on a seed is marked "not run"."""
    out = Path(out_dir)
    rows = []
    for result in RESULTS:
        scores = [_score_seed(result, _Runs(out, seed)) for seed in seeds]
        first = scores[0]
        tolerance = "; ".join(dict.fromkeys(b.text() for sc in scores for b in sc.bounds))
        if any(sc.missing for sc in scores):
            passed, marginal = None, False
            measured = next(sc.problem for sc in scores if sc.missing)
        elif any(sc.problem for sc in scores):
            passed, marginal = False, False
            measured = next(sc.problem for sc in scores if sc.problem)
        else:
            holds = all(b.holds() for sc in scores for b in sc.bounds)
            passed = all(b.holds(with_margin=True) for sc in scores for b in sc.bounds)
            marginal = holds and not passed
            measured = first.measured
            if len(seeds) > 1:
                measured += f" [seed {seeds[0]}; over seeds {_seed_list(seeds)}: {spread(scores)}]"
        rows.append(Row(**dc.asdict(result.claim), measured=measured, truth=first.truth,
                        tolerance=tolerance, passed=passed,
                        expected=result.expectation(quick), deviation=result.deviation,
                        marginal=marginal, strict=set(SEEDS) <= set(seeds),
                        images=first.images))
    return rows


#: The neural controller's runs the report gives window by window.
NN_WINDOW_RUNS = ("nn_styrofoam", "nn_rubber", "nn_styrofoam_sine", "nn_rubber_sine")
#: How many of the 5 s windows after contact it shows.
NN_WINDOWS = 5


def nn_window_table(out_dir, seeds) -> list[str]:
    """Markdown lines: for each of NN_WINDOW_RUNS that ran, the first seed's
    force RMSE in each 5 s window after contact, over 10-20 s, its hybrid
    part alone's over 10-20 s and its adaptation time; over every seed the
    range of the 10-20 s RMSE and the first contact loss. Empty if none ran."""
    def metrics(name, seed):
        path = run_folder(out_dir, name, seed) / "metrics.json"
        return json.loads(path.read_text()) if path.exists() else None

    def number(value, digits=2):
        return "-" if value is None else f"{value:.{digits}f}"

    first = seeds[0]
    header = (["run"] + [f"{5 * k}-{5 * k + 5} s" for k in range(NN_WINDOWS)]
              + ["10-20 s", "hybrid part alone, 10-20 s", "adaptation (s)",
                 f"10-20 s, seeds {_seed_list(seeds)}",
                 f"first contact loss after contact (s), seeds {_seed_list(seeds)}"])
    lines = []
    for name in NN_WINDOW_RUNS:
        m = metrics(name, first)
        if m is None:
            continue
        windows = list(m.get("force_rmse_windows_n") or [])[:NN_WINDOWS]
        windows += [None] * (NN_WINDOWS - len(windows))
        every = [metrics(name, seed) for seed in seeds]
        rmse = [e["force_rmse_n"] for e in every if e and e.get("force_rmse_n") is not None]
        losses = [number(e.get("first_contact_loss_s"), 1) if e and e.get("contact_losses")
                  else "none" for e in every if e]
        cells = ([f"`{name}`"] + [number(w) for w in windows]
                 + [number(m.get("force_rmse_n")), number(m.get("baseline_force_rmse_n")),
                    number(m.get("adaptation_time_s"), 1),
                    f"{min(rmse):.2f} to {max(rmse):.2f}" if rmse else "-", ", ".join(losses)])
        lines.append("| " + " | ".join(cells) + " |")
    if not lines:
        return []
    return ["## The neural controller, window by window", "",
            f"Force RMSE (true force against f_d, N) in each 5 s window after the first "
            f"contact, seed {first}; the hybrid part alone is the same run with the "
            "compensator removed; adaptation: from contact to the end of the first 5 s window "
            "(sliding by 0.5 s) under `scoring.adaptation_rmse_n` (1.5 N in these scenarios).", "",
            "| " + " | ".join(header) + " |", "|" + "---|" * len(header)] + lines + [""]


def _seed_list(seeds) -> str:
    seeds = list(seeds)
    if seeds == list(range(seeds[0], seeds[-1] + 1)) and len(seeds) > 2:
        return f"{seeds[0]}-{seeds[-1]}"
    return ", ".join(str(s) for s in seeds)


def parse_seeds(text: str) -> tuple[int, ...]:
    """``"0-2"``, ``"0,3,7"`` or ``"4"`` as a tuple of seeds; ValueError
    names what is wrong."""
    seeds = []
    for part in text.split(","):
        low, _, high = part.strip().partition("-")
        if not low.isdigit() or (high and not high.isdigit()):
            raise ValueError(f"'{part.strip()}' is not a seed or a range a-b of seeds >= 0")
        seeds += range(int(low), int(high or low) + 1)
    if not seeds or len(set(seeds)) != len(seeds):
        raise ValueError("must name each seed once")
    return tuple(seeds)


def run_folder(out: Path, scenario: str, seed: int) -> Path:
    """Where one scenario's run for one seed writes."""
    return Path(out) / scenario / f"seed_{seed}"


def job_point(job: Job, seed: int, *, quick: bool, first_seed: int) -> Point:
    """One scenario's run for one seed, as ``drake-contact run`` would do it:
    its figures; in --quick its short duration and no baseline, else the
    baseline (to the scoring window only where the job says so); the first
    seed's identification runs record a playback."""
    overrides = ()
    if quick and job.quick_duration_s is not None:
        overrides = (f"simulation.duration={job.quick_duration_s}",)
    baseline = False if quick else "window" if job.baseline_window else None
    return Point(run_folder(".", job.scenario, seed).as_posix(), job.scenario, overrides, seed,
                 baseline=baseline, figures=True, record=job.record and seed == first_seed)


def run_exit_status(run_dir: Path):
    """A run's outcome as ``drake-contact run``'s exit status: 0 completed,
    3 diverged, 130 interrupted, 1 raised; None: not run."""
    path = run_dir / "metrics.json"
    if path.exists():
        return {"completed": 0, "diverged": 3}.get(json.loads(path.read_text()).get("status"),
                                                   130)
    return 1 if failure_message(run_dir) is not None else None


class Reproduction(Campaign):
    """The reproduction as a campaign: a point per job and seed, written to
    ``DIR/<scenario>/seed_<s>/``; runs.csv has each run's outcome; the
    report's rows (:func:`score`) are scored across runs and seeds."""

    name = "reproduce"
    runs_folder = ""
    columns = {"runs": ["scenario", "seed", "exit_status", "status", "message"]}

    def __init__(self, out_dir, *, quick=False, seeds=SEEDS, progress=print):
        self.out, self.start = Path(out_dir), time.perf_counter()
        self.quick, self.seeds, self.progress = quick, tuple(seeds), progress
        self._points = {}
        for job in JOBS:
            for seed in self.seeds:
                point = job_point(job, seed, quick=quick, first_seed=self.seeds[0])
                self._points[point.name] = (job.scenario, seed, point)

    def points(self):
        return [point for _, _, point in self._points.values()]

    def score(self, point, run_dir):
        scenario, seed, _ = self._points[point.name]
        metrics = {}
        if (run_dir / "metrics.json").exists():
            metrics = json.loads((run_dir / "metrics.json").read_text())
        return {"runs": [{"scenario": scenario, "seed": seed,
                          "exit_status": run_exit_status(run_dir),
                          "status": metrics.get("status"),
                          "message": metrics.get("message") or failure_message(run_dir)}]}

    def aggregate(self, tables):
        return {"results": score(self.out, seeds=self.seeds, quick=self.quick),
                "claims": score_claims(self.out, seeds=self.seeds, quick=self.quick)}

    def resolved(self):
        return {"quick": self.quick, "seeds": list(self.seeds),
                "runs": {name: {"scenario": p.scenario, "seed": p.seed,
                                "overrides": list(p.overrides), "baseline": p.baseline,
                                "record": p.record}
                         for name, (_, _, p) in self._points.items()}}

    def report(self, out, result):
        status = {(row["scenario"], row["seed"]): row["exit_status"]
                  for row in result.tables["runs"]}
        path = write_report(out, result.tables["results"], quick=self.quick, status=status,
                            claims=result.tables["claims"],
                            seeds=self.seeds, interrupted=result.interrupted,
                            wall_s=time.perf_counter() - self.start)
        self.progress(f"wrote {path} and {path.with_suffix('.html')}")


#: The scenario whose diagram the report draws: the neural controller's,
#: which has every kind of block (arm, wall, sensor chain, DSP, controllers).
DIAGRAM_SCENARIO = "nn_styrofoam"


def write_diagram_drawing(out_dir) -> Path | None:
    """Writes ``diagram.dot`` in ``out_dir`` (the :data:`DIAGRAM_SCENARIO`
    diagram, one level of subsystems) and, when Graphviz's ``dot`` is
    installed, ``diagram.svg``; returns the SVG's path, or None without
    ``dot`` (a stale SVG is removed)."""
    # pydrake is imported here, not at the top: the reproduce command's
    # parent process otherwise only starts and scores runs.
    from drake_contact.app.drawing import diagram_dot, render_svg
    from drake_contact.diagram import MakeContactDiagram
    from drake_contact.scenario import load_scenario
    out = Path(out_dir)
    dot_text = diagram_dot(MakeContactDiagram(load_scenario(DIAGRAM_SCENARIO)))
    (out / "diagram.dot").write_text(dot_text)
    svg_text, svg = render_svg(dot_text), out / "diagram.svg"
    if svg_text is None:
        svg.unlink(missing_ok=True)
        return None
    svg.write_text(svg_text)
    return svg


def _natural(path: Path):
    """Sort key putting fig6_2 before fig6_11."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", path.name)]


def other_figures(out_dir, scenarios, shown, seed=0) -> dict[str, list[str]]:
    """Every ``*.png`` of one seed's runs (``out_dir/<scenario>/seed_<seed>/``
    and its ``baseline/``) that is not in ``shown``, as paths relative to
    ``out_dir``, by scenario: ``scenarios`` first, then any other folder in
    ``out_dir``."""
    out = Path(out_dir)
    folders = list(dict.fromkeys(scenarios)) + sorted(
        d.name for d in out.iterdir() if d.is_dir() and d.name not in scenarios)
    figures = {}
    for name in folders:
        run = run_folder(out, name, seed)
        images = [p.relative_to(out).as_posix()
                  for folder in (run, run / "baseline")
                  for p in sorted(folder.glob("*.png"), key=_natural)]
        images = [image for image in images if image not in shown]
        if images:
            figures[name] = images
    return figures


def figure_caption(image) -> str:
    """A caption from a figure's file name: ``identify_rubber/fig6_5_identification.png``
    -> "Fig 6.5: identification"; a hybrid-only baseline's says so."""
    path = PurePosixPath(image)
    match = re.fullmatch(r"fig(\d+)_(\d+)_(.+)", path.stem)
    caption = (f"Fig {match[1]}.{match[2]}: {match[3].replace('_', ' ')}" if match
               else path.stem.replace("_", " "))
    return caption + (" (hybrid-only baseline)" if path.parent.name == "baseline" else "")


def summary_line(rows) -> str:
    """How the rows came out against what we expect, in one sentence."""
    reproduced = sum(r.passed is True and r.expected for r in rows)
    deviations = sum(r.passed is False and not r.expected for r in rows)
    unexpected = [r.experiment for r in rows if r.passed is not None and not r.as_expected]
    missing = sum(r.passed is None for r in rows)
    return (f"{reproduced} of {len(rows)} results reproduced, {deviations} documented "
            f"deviations, {len(unexpected)} not as expected"
            + (f" ({', '.join(unexpected)})" if unexpected else "")
            + (f", {missing} not run" if missing else ""))


def _html_table(header, rows) -> str:
    """An HTML table: ``header``'s cells, then per row (cells, the verdict's
    CSS class, the verdict) with the verdict last, coloured by its class."""
    e = html.escape
    return ("<table><tr>" + "".join(f"<th>{e(h)}</th>" for h in header) + "</tr>"
            + "".join("<tr>" + "".join(f"<td>{e(c)}</td>" for c in cells)
                      + f"<td class='{cls}'>{e(verdict)}</td></tr>"
                      for cells, cls, verdict in rows) + "</table>")


def write_report(out_dir, rows, *, quick, status, claims=None, seeds=SEEDS,
                 interrupted=False, wall_s=None) -> Path:
    """Writes ``report.md`` and ``report.html`` (the thesis's claims first,
    then ``rows``: our forms beyond the thesis), ``claims.csv`` and the
    diagram's drawing (:func:`write_diagram_drawing`) in ``out_dir``;
    ``status`` is {(scenario, seed): exit status or None}; ``claims``
    defaults to scoring :data:`claims.CLAIMS` on ``out_dir``'s runs. Returns
    the Markdown's path."""
    out = Path(out_dir)
    if claims is None:
        claims = score_claims(out, seeds=seeds, quick=quick)
    thesis_claims.write_claims_csv(out / "claims.csv", claims, seeds)
    svg = write_diagram_drawing(out)
    diagram_md = (f"The `{DIAGRAM_SCENARIO}` diagram: [diagram.svg](diagram.svg) "
                  "(Graphviz DOT: [diagram.dot](diagram.dot))." if svg else
                  f"The `{DIAGRAM_SCENARIO}` diagram as Graphviz DOT text: "
                  "[diagram.dot](diagram.dot) (`apt-get install graphviz` renders it).")
    shown = {image for r in rows for image in r.images}
    scenarios = [name for name, _ in status]
    others = other_figures(out, scenarios, shown, seeds[0])
    title = "drake_contact: the thesis reproduced" + (" (quick)" if quick else "")
    summary = (thesis_claims.summary(claims) + f"; beyond the thesis: {summary_line(rows)}"
               + f", over seeds {_seed_list(seeds)}"
               + (" — INTERRUPTED: partial report" if interrupted else "")
               + (f"; {wall_s:.0f} s wall time" if wall_s is not None else "") + ".")
    mode = ("--quick: long runs shortened, no hybrid-only baselines (the full run: "
            "`drake-contact reproduce --out DIR`)." if quick else "Full run.")
    claims_rule = ("Each claim of the thesis in its own words, on its own forms, with the "
                   "criterion written before the results were seen; a claim is reproduced when "
                   "it holds on every seed. Calibration rows (fitted, or tied to a fitted "
                   "parameter) are shown, not counted. Values per seed; claims.csv has them all.")
    rule = ("Beyond the thesis: our forms against the ground truth. A result is reproduced "
            "when every seed meets every bound by the bound's margin "
            f"(figures: seed {seeds[0]}).")
    claim_deviations = [r for r in claims if r.claim.deviation or r.claim.calibration]
    header = ["experiment", "thesis figure", "thesis reports", "measured (ours)",
              "ground truth", "bounds", "result"]

    md = [f"# {title}", "", summary, "", mode, "", "## The thesis's claims", "",
          claims_rule, ""]
    md += thesis_claims.markdown_table(claims, seeds)
    if claim_deviations:
        md += ["", "### Causes and calibration", ""]
        md += [f"- {r.claim.id} (line {r.claim.lines}): "
               f"{r.claim.deviation or r.claim.calibration}." for r in claim_deviations]
    md += ["", "## Beyond the thesis", "", rule, "",
           "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for r in rows:
        cells = [r.experiment, r.figures, r.thesis, r.measured, r.truth, r.tolerance, r.verdict()]
        md.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    deviations = [r for r in rows if r.deviation]
    if deviations:
        md += ["", "## Documented deviations", ""]
        md += [f"- {r.experiment} (Fig {r.figures}): {r.deviation}." for r in deviations]
    md += [""] + nn_window_table(out, seeds)
    md += ["## The diagram", "", diagram_md, "", "## Runs", ""]
    for (name, seed), code in status.items():
        folder = run_folder(".", name, seed).as_posix()
        md.append(f"- `{name}` seed {seed}: " + ("not started" if code is None else f"exit {code}")
                  + f" ([metrics]({folder}/metrics.json), [log]({folder}/run.log))")
    playbacks = [f"{run_folder('.', name, seeds[0]).as_posix()}/playback.html"
                 for name in dict.fromkeys(scenarios)
                 if (run_folder(out, name, seeds[0]) / "playback.html").exists()]
    if playbacks:
        md += ["", "Meshcat playbacks (open in a browser): "
               + ", ".join(f"[{p}]({p})" for p in playbacks)]
    md += ["", "## Figures", ""]
    for r in rows:
        if r.images:
            md += [f"### Fig {r.figures}: {r.experiment}", ""]
            md += [f"![{image}]({image})" for image in r.images] + [""]
    if others:
        md += ["## Every other figure, by run", ""]
    for name, images in others.items():
        md += [f"### {name}", ""]
        md += [f"![{figure_caption(image)}]({image})" for image in images] + [""]
    path = out / "report.md"
    path.write_text("\n".join(md) + "\n")

    e = html.escape
    body = [f"<h1>{e(title)}</h1>", f"<p>{e(summary)}</p>", f"<p>{e(mode)}</p>",
            "<h2>The thesis's claims</h2>", f"<p>{e(claims_rule)}</p>"]
    body.append(_html_table(
        thesis_claims.TABLE_COLUMNS + [f"seed {s}" for s in seeds] + ["verdict"],
        [(thesis_claims.claim_cells(r.claim) + [thesis_claims.seed_values(r, s) for s in seeds],
          "missing" if r.reproduced is None else "fail" if not r.as_expected
          else "deviation" if r.claim.calibration or r.claim.deviation else "pass", r.verdict)
         for r in claims]))
    if claim_deviations:
        body.append("<h3>Causes and calibration</h3><ul>" + "".join(
            f"<li>{e(r.claim.id)} (line {e(r.claim.lines)}): "
            f"{e(r.claim.deviation or r.claim.calibration)}.</li>" for r in claim_deviations)
            + "</ul>")
    body += ["<h2>Beyond the thesis</h2>", f"<p>{e(rule)}</p>"]
    body.append(_html_table(header, [
        ([r.experiment, r.figures, r.thesis, r.measured, r.truth, r.tolerance],
         "missing" if r.passed is None else "pass" if r.passed and r.expected
         else "deviation" if r.as_expected else "fail", r.verdict()) for r in rows]))
    if deviations:
        body.append("<h2>Documented deviations</h2><ul>" + "".join(
            f"<li>{e(r.experiment)} (Fig {e(r.figures)}): {e(r.deviation)}.</li>"
            for r in deviations) + "</ul>")
    body.append("<h2>The diagram</h2>")
    if svg:
        body.append(f"<figure><img src='diagram.svg' alt='the {DIAGRAM_SCENARIO} diagram'>"
                    f"<figcaption>The {DIAGRAM_SCENARIO} diagram, one level of subsystems "
                    "(<a href='diagram.dot'>Graphviz DOT</a>)</figcaption></figure>")
    else:
        body.append(f"<p>The {DIAGRAM_SCENARIO} diagram as Graphviz DOT text: "
                    "<a href='diagram.dot'>diagram.dot</a> (<code>apt-get install graphviz"
                    "</code> draws it here).</p>")
    if playbacks:
        body.append("<p>Meshcat playbacks: " + ", ".join(
            f"<a href='{e(p)}'>{e(p)}</a>" for p in playbacks) + "</p>")
    body.append("<h2>Figures</h2>")
    for r in rows:
        for image in r.images:
            body.append(f"<figure><img src='{e(image)}' alt='{e(image)}'>"
                        f"<figcaption>Fig {e(r.figures)}: {e(r.experiment)}</figcaption></figure>")
    if others:
        body.append("<h2>Every other figure, by run</h2>")
    for name, images in others.items():
        body.append(f"<h3>{e(name)}</h3>")
        for image in images:
            body.append(f"<figure><img src='{e(image)}' alt='{e(image)}'>"
                        f"<figcaption>{e(figure_caption(image))}</figcaption></figure>")
    style = ("body{font-family:sans-serif;max-width:1200px;margin:auto}"
             "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:4px;"
             "vertical-align:top;font-size:13px}.pass{background:#cfc}.fail{background:#fcc}"
             ".deviation{background:#fec}.missing{background:#eee}img{max-width:100%}")
    (out / "report.html").write_text(
        f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{e(title)}</title>"
        f"<style>{style}</style></head><body>{''.join(body)}</body></html>\n")
    return path


def reproduce(out_dir, *, quick=False, jobs=None, seeds=SEEDS,
              progress=print, ensemble=DEFAULT_ENSEMBLE
              ) -> tuple[list[Row], list[thesis_claims.ClaimRow], bool]:
    """Runs everything over ``seeds`` on ``jobs`` local workers (default one
    per core; the runs that share a controller in ensembles of up to
    ``ensemble``) and writes the report; returns (the rows beyond the
    thesis, the thesis's claims, interrupted)."""
    campaign = Reproduction(out_dir, quick=quick, seeds=seeds, progress=progress)

    def finished(done, failed, total, eta_s, name):
        status = run_exit_status(Path(out_dir) / name)
        progress(f"finished {name} (exit {status}) [{done}/{total}, ETA {eta_s:.0f} s]")
    result = run_campaign(campaign, out_dir, workers=jobs, progress=finished,
                          ensemble=ensemble)
    return result.tables["results"], result.tables["claims"], result.interrupted
