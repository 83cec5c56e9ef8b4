"""The reference results' snapshots (docs/results/): each is stamped with the
fingerprint of what it depends on, and is stale, naming the command that
refreshes it, once the physics or its study's definition changes. The
tests read the snapshots; they never rerun a study."""

import importlib.util
import json
import shutil
from pathlib import Path

import pytest

DOCS = Path(__file__).resolve().parents[1] / "docs"
_spec = importlib.util.spec_from_file_location("docs_results", DOCS / "results.py")
results = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(results)


@pytest.mark.parametrize("name", sorted(results.STUDIES))
def test_every_snapshot_matches_the_code(name):
    reason = results.stale(name)
    assert reason is None, (f"docs/results/{name} is stale ({reason}): refresh it with "
                            f"`{results.refresh_command(name)}` and commit docs/results/{name}")


def test_a_physics_change_makes_a_snapshot_stale_and_names_its_refresh(tmp_path):
    """A golden log re-recorded (one byte of it changed, in a copy) is a
    change of physics: the snapshot made before it is stale."""
    golden = tmp_path / "golden"
    shutil.copytree(results.GOLDEN, golden)
    snapshots = tmp_path / "results"
    (snapshots / "faults").mkdir(parents=True)
    stamp = {"fingerprint": results.fingerprint("faults", golden)}
    (snapshots / "faults" / "snapshot.json").write_text(json.dumps(stamp))
    assert results.stale("faults", snapshots, golden) is None
    log = sorted(golden.glob("*.npz"))[0]
    data = bytearray(log.read_bytes())
    data[len(data) // 2] ^= 1
    log.write_bytes(bytes(data))
    assert results.stale("faults", snapshots, golden) == "physics changed since it was made"


def test_a_change_of_a_studys_definition_makes_its_snapshot_stale(monkeypatch, tmp_path):
    snapshots = tmp_path / "results"
    (snapshots / "faults").mkdir(parents=True)
    stamp = {"fingerprint": results.fingerprint("faults")}
    (snapshots / "faults" / "snapshot.json").write_text(json.dumps(stamp))
    from drake_contact.app import fault_study
    monkeypatch.setattr(fault_study, "FAULT_START_S", 6.0)
    assert results.stale("faults", snapshots) == "definition changed since it was made"


def test_the_snapshots_are_small():
    size = sum(p.stat().st_size for p in (DOCS / "results").rglob("*") if p.is_file())
    assert size < 8e6, f"docs/results/ is {size / 1e6:.1f} MB"


def _generated_studies() -> dict:
    """study -> the pages whose ``generated`` directives show it."""
    import re
    found = {}
    for page in DOCS.rglob("*.md"):
        if "results" in page.relative_to(DOCS).parts[:1] or "_build" in page.parts:
            continue
        for study in re.findall(r"^```\{generated\} (\S+)", page.read_text(), re.M):
            found.setdefault(study, []).append(page.relative_to(DOCS).as_posix())
    return found


def test_every_study_a_page_shows_has_a_snapshot_and_every_snapshot_is_shown():
    shown = _generated_studies()
    assert set(shown) <= set(results.STUDIES), set(shown) - set(results.STUDIES)
    assert set(results.STUDIES) <= set(shown), set(results.STUDIES) - set(shown)
    for name in results.STUDIES:
        assert (DOCS / "results" / name / "snapshot.json").exists(), (
            f"docs/results/{name} is missing: make it with `{results.refresh_command(name)}`")


def test_the_readme_status_is_the_reproductions_snapshot():
    readme = (DOCS.parent / "README.md").read_text()
    assert results.readme_with_status(readme) == readme, (
        "README.md's status is not the reproduction's snapshot: write it with "
        "`python docs/results.py --readme`")
    assert results.readme_status().startswith("**Status** (the reference reproduction, seeds 0-2")


def test_a_campaign_with_failed_runs_leaves_no_snapshot(monkeypatch, tmp_path):
    """A campaign exits 1 when runs failed (raised, or their worker died):
    its results are not reference results. The reproduction exits 1 when a
    result is not as expected, which its snapshot shows."""
    import subprocess
    monkeypatch.setattr(results, "RESULTS", tmp_path / "results")
    monkeypatch.setattr(results, "GENERATED", tmp_path / "generated")
    monkeypatch.setattr(results.subprocess, "run",
                        lambda *a, **k: subprocess.CompletedProcess(a, 1))
    written = []
    monkeypatch.setattr(results, "write_snapshot", lambda *a, **k: written.append(a[0]))
    monkeypatch.setattr(results, "readme_with_status", lambda text, *a: text)
    assert results.refresh("benchmark") == 1 and written == []
    assert results.refresh("robust_nn") == 1 and written == []
    monkeypatch.setattr(results, "README", tmp_path / "README.md")
    (tmp_path / "README.md").write_text("x")
    assert results.refresh("reproduce") == 0 and written == ["reproduce"]
