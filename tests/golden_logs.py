"""Golden logs: short logs of every bundled scenario across its contact
switch, stored in ``tests/golden/<scenario>.npz``, that every later change
is held to (``tests/test_golden_logs.py``).

Each fixture holds the run's every logged signal at 1 kHz over the last
:data:`WINDOW_S` before its end (the switch and the first 0.35 s of contact
for the contact scenarios), and every :data:`DECIMATE`-th sample before
that, plus the versions of the packages that computed it.

Re-record (only when a change must alter the physics or reorder its
floating-point arithmetic, and say which and why in its commit)::

    python tests/golden_logs.py [SCENARIO ...]

Before re-recording, measure how far the change moves each signal::

    python tests/golden_logs.py --compare [SCENARIO ...]

prints, per scenario, the signals that moved: the largest deviation
relative to the signal's scale (its largest magnitude in the fixture), and
when it first exceeds 1e-9 of that scale.
"""

import ctypes
import json
import platform
import sys
from importlib import metadata
from pathlib import Path

import numpy as np

GOLDEN_DIR = Path(__file__).resolve().parent / "golden"

#: Full-rate samples kept at the end of each golden run (s).
WINDOW_S = 0.4
#: Samples kept before the window: every DECIMATE-th.
DECIMATE = 100
#: How far past the contact switch a contact scenario's golden run goes (s).
AFTER_SWITCH_S = 0.35
#: Where the run ends for scenarios without a contact switch (s).
FIXED_END_S = {"push_constant": 2.5, "sensor_spectrum": 4.2}
#: Packages whose floating-point order the logs depend on.
PACKAGES = ("drake", "numpy", "scipy")


def versions() -> dict:
    """The package versions, and the CPU kernels numpy dispatches to: the
    same versions on another CPU (another OpenBLAS core, other SIMD) sum in
    another order. Measured: the fixtures recorded on one cloud CPU and run
    on another differ by up to 1e-12 of scale in the neural scenarios."""
    return {name: metadata.version(name) for name in PACKAGES} | {"cpu": cpu_kernels()}


def cpu_kernels() -> str:
    """The machine, numpy's enabled SIMD features and OpenBLAS's core, e.g.
    ``x86_64 AVX,AVX2,... Haswell``; a part that cannot be read is ``?``."""
    try:
        from numpy._core._multiarray_umath import __cpu_features__
        simd = ",".join(sorted(name for name, on in __cpu_features__.items() if on))
    except ImportError:
        simd = "?"
    core = "?"
    libs = Path(np.__file__).resolve().parent.parent / "numpy.libs"
    for lib in sorted(libs.glob("libscipy_openblas*.so")):
        for symbol in ("scipy_openblas_get_corename64_", "scipy_openblas_get_corename"):
            get = getattr(ctypes.CDLL(str(lib)), symbol, None)
            if get is not None:
                get.restype = ctypes.c_char_p
                core = get().decode()
                break
    return f"{platform.machine()} {simd} {core}"


def simulate_log(scenario_name: str, duration: float) -> dict:
    """The log dict of a bundled scenario simulated for ``duration`` s."""
    from drake_contact import load_scenario, simulate_scenario
    result = simulate_scenario(load_scenario(scenario_name, duration=duration))
    assert result.status == "completed", result.message
    return result.log


def select(log: dict, end_s: float) -> dict:
    """The fixture's rows of a log ending at ``end_s``."""
    t = log["t"]
    window = t >= end_s - WINDOW_S - 1e-9
    before = ~window & (np.arange(len(t)) % DECIMATE == 0)
    keep = window | before
    return {key: np.asarray(value)[keep] for key, value in log.items()}


def golden_end_s(scenario_name: str) -> float:
    """Where the golden run of a scenario ends, as recorded."""
    return float(load_golden(scenario_name)["end_s"])


def load_golden(scenario_name: str) -> dict:
    with np.load(GOLDEN_DIR / f"{scenario_name}.npz") as data:
        return {key: data[key] for key in data.files}


def record(scenario_name: str) -> Path:
    if scenario_name in FIXED_END_S:
        end_s = FIXED_END_S[scenario_name]
    else:
        probe = simulate_log(scenario_name, 9.0)
        switch = probe["t"][int(np.argmax(probe["mode"] > 0))]
        assert probe["mode"].max() > 0, f"{scenario_name}: no contact switch by 9 s"
        end_s = round(float(switch) + AFTER_SWITCH_S, 3)
    log = select(simulate_log(scenario_name, end_s), end_s)
    path = GOLDEN_DIR / f"{scenario_name}.npz"
    GOLDEN_DIR.mkdir(exist_ok=True)
    np.savez_compressed(path, **{f"log/{k}": v for k, v in log.items()},
                        end_s=np.float64(end_s), versions=json.dumps(versions()))
    return path


def compare(scenario_name: str) -> list:
    """[(signal, largest |deviation| / scale, first time above 1e-9 of the
    scale)] of the current code against the fixture, largest first; signals
    that did not move are left out."""
    golden = load_golden(scenario_name)
    end_s = float(golden["end_s"])
    log = select(simulate_log(scenario_name, end_s), end_s)
    t = golden["log/t"]
    rows = []
    for key in (k for k in golden if k.startswith("log/") and k != "log/t"):
        expected, actual = golden[key], np.asarray(log[key[len("log/"):]])
        scale = float(np.max(np.abs(expected), initial=0.0)) or 1.0
        deviation = np.abs(actual - expected).reshape(len(t), -1).max(axis=1) / scale
        if deviation.max() > 0:
            first = float(t[int(np.argmax(deviation > 1e-9))]) if deviation.max() > 1e-9 else None
            rows.append((key[len("log/"):], float(deviation.max()), first))
    return sorted(rows, key=lambda row: -row[1])


if __name__ == "__main__":
    from drake_contact.resources import bundled_scenario_names
    args = sys.argv[1:]
    if args and args[0] == "--compare":
        for name in args[1:] or bundled_scenario_names():
            rows = compare(name)
            print(f"{name}: {len(rows)} signals moved"
                  + "".join(f"\n  {signal:32s} {dev:9.2e}"
                            + (f"  from t = {first:.3f} s" if first is not None else "")
                            for signal, dev, first in rows))
    else:
        for name in args or bundled_scenario_names():
            path = record(name)
            print(f"{name}: {path.stat().st_size / 1e3:.0f} kB, end {golden_end_s(name):.3f} s")
