"""The thesis's claims table (drake_contact.app.claims): each claim quotes the
thesis at the lines it names, states a criterion, and a claim the model does
not reproduce states its cause; the measures against hand computations on
synthetic logs; verdicts over seeds; claims.csv."""

import csv
import json
import re
from pathlib import Path

import numpy as np
import pytest

from drake_contact.app import claims
from drake_contact.app.claims import CLAIMS, Missing, score_claims

THESIS = Path(__file__).resolve().parents[1] / claims.THESIS_TEXT


def _words(text):
    return re.sub(r"\s+", " ", text).strip()


@pytest.mark.skipif(not THESIS.exists(), reason=f"the thesis's text is not at {THESIS}")
def test_every_claim_quotes_the_thesis_at_the_lines_it_names():
    lines = THESIS.read_text().splitlines()
    for claim in CLAIMS:
        named = " ".join(lines[int(n) - 1] for n in re.findall(r"\d+", claim.lines))
        # A quote may leave words out ("..."), and S4 adds what the code means
        # in parentheses.
        quote = claim.claim.split("  (")[0]
        for fragment in quote.split("..."):
            fragment = _words(fragment).strip(" .")
            assert fragment and fragment in _words(named), (claim.id, fragment)


def test_the_table_is_complete_and_each_claim_states_its_criterion():
    ids = [claim.id for claim in CLAIMS]
    assert len(set(ids)) == len(ids)
    assert 25 <= sum(not c.calibration for c in CLAIMS) <= 40
    for claim in CLAIMS:
        assert claim.runs and len(claim.criterion) > 10, claim.id
        assert not (claim.deviation and claim.calibration), claim.id
        if claim.deviation:
            # A cause, or "not isolated" with what was tried.
            assert len(claim.deviation) > 80, claim.id
    assert set(claims.DEVIATIONS) <= set(ids)


def _metrics_reader(store):
    def metrics(out, name, seed):
        if (name, seed) not in store:
            raise Missing(name)
        return store[name, seed]
    return metrics


def test_missing_runs_are_not_run_and_not_as_expected(tmp_path):
    rows = score_claims(tmp_path, (0, 1, 2), _metrics_reader({}))
    assert all(r.verdict == "not run" for r in rows if not r.claim.calibration)
    assert not any(r.as_expected for r in rows if not r.claim.calibration)
    quick = score_claims(tmp_path, (0,), _metrics_reader({}), quick=True)
    skipped = [r.claim.id for r in quick if r.skipped]
    assert skipped == [c.id for c in CLAIMS if not c.quick] and "H5" in skipped
    assert all(r.as_expected and r.verdict == "not scored in --quick"
               for r in quick if r.skipped)


def _identification_log(t_switch=1.0, k_final=7000.0, settle_s=0.2, duration=6.0):
    """A log whose rls K_e starts at 2e5 and steps to k_final settle_s after
    the switch; f / x is not needed by the settling measure."""
    t = np.round(np.arange(0.0, duration, 0.001), 6)
    k = np.where(t < t_switch + settle_s, 2e5, k_final)
    impedance = np.stack([np.zeros_like(t), np.zeros_like(t), k], axis=1)
    info = np.tile([t_switch, 0.456, 0.0, 0.0], (len(t), 1))
    return {"t": t, "contact_info": info, "impedance_rls": impedance}


def _seed_with(tmp_path, logs, metrics=None):
    seed = claims.Seed(tmp_path, 0, lambda name: (metrics or {}).get(name, {}))
    seed._logs = {tmp_path / name / "seed_0": log for name, log in logs.items()}
    return seed


def test_identified_after_is_the_time_the_estimate_settles_near_its_figure_end_value(tmp_path):
    seed = _seed_with(tmp_path, {"run": _identification_log(settle_s=0.2)})
    assert claims.identified_after(seed, "run", "rls") == pytest.approx(0.2)
    # A late excursion past 10 % of the 4 s value counts; one within it does not.
    log = _identification_log(settle_s=0.05)
    log["impedance_rls"][2500, 2] = 7000.0 * 1.11
    log["impedance_rls"][3000, 2] = 7000.0 * 1.09
    seed = _seed_with(tmp_path, {"run": log})
    assert claims.identified_after(seed, "run", "rls") == pytest.approx(1.501)


def _tracking_log(offsets, t_switch=1.0, half_period=2.5, duration=12.0):
    """f_d 20 then 10 N, alternating every half_period from the switch; the
    measured force sits at f_d + offsets[level index] (N)."""
    t = np.round(np.arange(0.0, duration, 0.001), 6)
    index = np.floor((t - t_switch) / half_period + 1e-9).astype(int)
    f_d = np.where(t < t_switch, 0.0, np.where(index % 2 == 0, 20.0, 10.0))
    force = f_d + np.array([offsets[min(i, len(offsets) - 1)] if i >= 0 else 0.0
                            for i in index])
    info = np.tile([t_switch, 0.456, 0.0, 0.0], (len(t), 1))
    return {"t": t, "contact_info": info, "force_desired": f_d, "force_filtered": force}


def test_level_shortfall_counts_short_of_a_raised_level_and_above_a_lowered_one(tmp_path):
    # Short by 2 N on the 20 N level and 3 N above the 10 N level.
    log = _tracking_log([-2.0, +3.0, -2.0, +3.0])
    assert claims.level_shortfalls(_seed_with(tmp_path, {"r": log}), "r") == pytest.approx(2.0)
    # Past a level (21 N on a 20 N level, 8.5 N on a 10 N one) is a negative
    # shortfall; the smallest over the levels counts.
    log = _tracking_log([+1.0, +3.0, +1.0, +3.0])
    assert claims.level_shortfalls(_seed_with(tmp_path, {"r": log}), "r") == pytest.approx(-1.0)
    log = _tracking_log([-2.0, -1.5, -2.0, -1.5])
    assert claims.level_shortfalls(_seed_with(tmp_path, {"r": log}), "r") == pytest.approx(-1.5)


def test_follows_ratio_is_the_slot_rmse_over_the_hybrid_part_alones(tmp_path):
    run, base = _tracking_log([0.5], duration=20.0), _tracking_log([2.0], duration=20.0)
    seed = _seed_with(tmp_path, {"r": run})
    seed._logs[tmp_path / "r" / "seed_0" / "baseline"] = base
    assert claims.follows_ratio(seed, "r") == pytest.approx(0.25)
    # A slot past the run's end is not scored, not failed.
    with pytest.raises(Missing):
        claims.follows_ratio(seed, "r", start_s=16.0)


def _fake_identification(out, seed, k_rls, fx):
    run = out / "identify_styrofoam" / f"seed_{seed}"
    run.mkdir(parents=True)
    metrics = {"status": "completed", "stiffness_ratio_final_n_per_m": fx,
               "identified_impedance_rls": {"mass": -0.1, "damping": 80.0,
                                            "stiffness": k_rls}}
    (run / "metrics.json").write_text(json.dumps(metrics))
    return metrics


def test_a_claim_is_reproduced_only_on_every_seed_and_a_deviation_only_while_it_deviates(
        tmp_path):
    store = {("identify_styrofoam", s): _fake_identification(tmp_path, s, k, 7000.0)
             for s, k in enumerate([7100.0, 7300.0, 7500.0])}
    # R3 as a plain claim (it is a calibration row: an RLS's K_e against f / x).
    r3 = claims.dc.replace(next(c for c in CLAIMS if c.id == "R3"), calibration="")
    assert not r3.deviation
    (row,) = score_claims(tmp_path, (0, 1, 2), _metrics_reader(store), claims=[r3])
    assert row.holds == {0: True, 1: True, 2: False}  # 7500 is 7.1 % off
    assert row.reproduced is False and not row.as_expected
    assert row.verdict == "not as expected (does not hold)"
    # The same claim documented as a deviation: as expected while it fails,
    # not when it holds on every documented seed (a strict xfail), and
    # as expected on fewer seeds.
    documented = claims.dc.replace(r3, deviation="x" * 90)
    (row,) = score_claims(tmp_path, (0, 1, 2), _metrics_reader(store), claims=[documented])
    assert row.as_expected and row.verdict == "documented deviation"
    (row,) = score_claims(tmp_path, (0, 1), _metrics_reader(store), claims=[documented])
    assert row.reproduced and row.as_expected and row.verdict.startswith("holds on these seeds")
    store = {key: value for key, value in store.items() if key[1] < 2}
    store["identify_styrofoam", 2] = _fake_identification(tmp_path / "b", 2, 7000.0, 7000.0)
    (row,) = score_claims(tmp_path, (0, 1, 2), _metrics_reader(store), claims=[documented])
    assert not row.as_expected and "now holds" in row.verdict


def test_claims_csv_has_one_line_per_claim_and_seed(tmp_path):
    store = {("identify_styrofoam", s): _fake_identification(tmp_path, s, 7000.0, 7000.0)
             for s in (0, 1)}
    rows = score_claims(tmp_path, (0, 1), _metrics_reader(store))
    claims.write_claims_csv(tmp_path / "claims.csv", rows, (0, 1))
    with open(tmp_path / "claims.csv", newline="") as stream:
        lines = list(csv.DictReader(stream))
    assert list(lines[0]) == claims.CSV_COLUMNS
    assert len(lines) == 2 * len(CLAIMS)
    r3 = [line for line in lines if line["id"] == "R3"]
    assert [line["holds"] for line in r3] == ["True", "True"]
    assert r3[0]["values"] == "k_e=7000; fx_n_per_m=7000"
    assert r3[0]["verdict"] == "calibration (holds)" and r3[0]["cause"] == claims.RLS_TIED
    n5 = next(line for line in lines if line["id"] == "N5")
    assert n5["verdict"] == "not run" and n5["cause"].startswith("nn K_e reads")
