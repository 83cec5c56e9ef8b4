"""The suite's own machinery: tests marked with one xdist group run on one
worker, which the shared runs rely on (docs/developer/testing.md, "Shared runs")."""

import os

import pytest

pytestmark = pytest.mark.xdist_group("test_suite")

_WORKERS = []


@pytest.mark.parametrize("i", range(4))
def test_a_group_runs_on_one_worker(request, i):
    """Under ``--dist loadgroup`` pytest-xdist sends a group's tests to one
    worker by suffixing their node ids with ``@<group>``. pytest 9.2 stopped
    honouring that suffix (pytest-dev/pytest-xdist#1386): every group was
    then spread over the workers and every shared run ran once per worker,
    with nothing failing. This fails instead."""
    worker = os.environ.get("PYTEST_XDIST_WORKER")
    if worker is None or not request.config.getvalue("loadgroup"):
        pytest.skip("not under pytest-xdist's --dist loadgroup")
    assert request.node.nodeid.endswith("@test_suite"), request.node.nodeid
    _WORKERS.append(worker)
    assert set(_WORKERS) == {worker}
