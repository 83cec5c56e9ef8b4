"""Golden logs: short logs of every bundled scenario across its contact
switch, stored in ``tests/golden/<scenario>.npz``, that every later change
is held to (``tests/test_golden_logs.py``).

Each fixture holds the run's every logged signal at 1 kHz over the last
:data:`WINDOW_S` before its end (the switch and the first 0.35 s of contact
for the contact scenarios), and every :data:`DECIMATE`-th sample before
that; the versions and CPU kernels that computed it; and, per signal and
sample, its measured sensitivity to rounding (``sensitivity/<signal>``).

Why a sensitivity and not a fixed tolerance. The closed loop amplifies
rounding: the LuGre joints' stick-slip and the encoder and ADC quantizers
turn a last-bit difference into a different trajectory, from the contact
switch on. Another CPU (OpenBLAS picks its kernels by CPU, and they sum in
another order) moves the identification scenarios by up to 4e-6 of a
signal's scale 0.35 s after the switch, and by nothing before it. So the
fixture records how far each signal moves, sample by sample, when the
recording machine reruns the scenario with the rounding disturbed
(:data:`SENSITIVITY_RUNS`: one joint's motor torque or the force reading
off by a relative :data:`PERTURBATION` from the first contact on;
:data:`KERNEL_RUNS`: OpenBLAS's other kernels this CPU can run), and the
comparison allows :data:`MARGIN` times that (never less than :data:`FLOOR`
of the scale). Before the switch, where nothing is amplified, that leaves
a tolerance of about 1e-9 of the scale; after it, the allowance grows as
the measured sensitivity does.

Re-record (only for a change of physics, in its own commit with the
``--compare`` output in its message; never because the machine changed)::

    python tests/golden_logs.py [SCENARIO ...]

Measure how far the current code is from the fixtures, per scenario the
largest deviation as a fraction of its allowance::

    python tests/golden_logs.py --compare [SCENARIO ...]

Add the sensitivity to fixtures that lack it, leaving their logs as they
are (it is measured against this machine's own run of the scenario)::

    python tests/golden_logs.py --sensitivity [SCENARIO ...]
"""

import ctypes
import dataclasses as dc
import json
import os
import platform
import subprocess
import sys
import tempfile
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

#: The allowance: this multiple of the largest deviation the sensitivity
#: runs showed (chaos grows exponentially, so a factor of 100 is a few
#: milliseconds of growth more than any disturbance the recording machine
#: produced).
MARGIN = 10.0
#: The allowance is never below this fraction of the signal's scale.
FLOOR = 1e-9
#: Rounding may first show this much earlier than it did in the
#: sensitivity runs (s): the allowance at t is the largest sensitivity up to
#: t + LEAD_S.
LEAD_S = 0.02
#: Signals that are counts of a quantum (encoder counts, ADC codes, modes):
#: after the contact switch they may differ by one quantum (the column's
#: smallest step in the fixture) on at most QUANTIZED_FRACTION of the
#: samples, where a rounding difference tips a reading over a threshold.
QUANTIZED = ("joint_positions_measured", "force_measured", "mode", "safety_state",
             "safety_stop_reason", "fault_active")
QUANTIZED_FRACTION = 0.02
#: Sensitivity runs: from the first contact on (the first sample with a
#: true contact force above 5 N, when the identifiers and the contact laws,
#: whose numpy arithmetic differs between CPUs, start), one joint's motor
#: torque or the force reading off by a relative PERTURBATION at every
#: sample. Each is a scenario fault: {run: (fault kind, joint, factor)}.
#: Why not one ulp: another CPU differs by more than one ulp per sample
#: (OpenBLAS's small-matrix kernels and numpy's AVX-512 transcendental
#: functions round differently in many operations): measured, the fixtures
#: recorded with SkylakeX kernels and rerun with Haswell's moved
#: identify_styrofoam's rls_matched 1500 times as far as one ulp on the
#: force reading did, and 20 times as far as a run under any other OpenBLAS
#: kernel this CPU can run.
PERTURBATION = 1e-7
SENSITIVITY_RUNS = {
    "torque_joint1_plus": ("motor_scale", 0, 1 + PERTURBATION),
    "torque_joint2_minus": ("motor_scale", 1, 1 - PERTURBATION),
    "torque_joint3_plus": ("motor_scale", 2, 1 + PERTURBATION),
    "force_reading_plus": ("force_gain", 0, 1 + PERTURBATION),
    "force_reading_minus": ("force_gain", 0, 1 - PERTURBATION),
}
#: Sensitivity runs: OpenBLAS kernels run in a subprocess
#: (``OPENBLAS_CORETYPE``), those of them this CPU can run and that differ
#: from its own.
KERNEL_RUNS = ("SkylakeX", "Haswell", "Sandybridge", "Nehalem", "Prescott")


def versions() -> dict:
    """The package versions, and the CPU kernels numpy dispatches to."""
    return {name: metadata.version(name) for name in PACKAGES} | {"cpu": cpu_kernels()}


def cpu_kernels() -> str:
    """The machine, numpy's enabled SIMD features and OpenBLAS's core, e.g.
    ``x86_64 AVX,AVX2,... Haswell``; a part that cannot be read is ``?``."""
    try:
        from numpy._core._multiarray_umath import __cpu_features__
        simd = ",".join(sorted(name for name, on in __cpu_features__.items() if on))
    except ImportError:
        simd = "?"
    return f"{platform.machine()} {simd} {openblas_core()}"


def openblas_core() -> str:
    """The OpenBLAS core numpy's OpenBLAS runs (``?`` if unknown)."""
    libs = Path(np.__file__).resolve().parent.parent / "numpy.libs"
    for lib in sorted(libs.glob("libscipy_openblas*.so")):
        for symbol in ("scipy_openblas_get_corename64_", "scipy_openblas_get_corename"):
            get = getattr(ctypes.CDLL(str(lib)), symbol, None)
            if get is not None:
                get.restype = ctypes.c_char_p
                return get().decode()
    return "?"


def simulate_log(scenario_name: str, duration: float, overrides=()) -> dict:
    """The log dict of a bundled scenario simulated for ``duration`` s."""
    from drake_contact import load_scenario, simulate_scenario
    result = simulate_scenario(load_scenario(scenario_name, list(overrides), duration=duration))
    assert result.status == "completed", result.message
    return result.log


def select(log: dict, end_s: float) -> dict:
    """The fixture's rows of a log ending at ``end_s``."""
    t = log["t"]
    window = t >= end_s - WINDOW_S - 1e-9
    before = ~window & (np.arange(len(t)) % DECIMATE == 0)
    keep = window | before
    return {key: np.asarray(value)[keep] for key, value in log.items()}


def golden_log(scenario_name: str, overrides=()) -> dict:
    """The current code's run of a scenario, cut as its fixture is."""
    end_s = golden_end_s(scenario_name)
    return select(simulate_log(scenario_name, end_s, overrides), end_s)


def golden_end_s(scenario_name: str) -> float:
    """Where the golden run of a scenario ends, as recorded."""
    return float(load_golden(scenario_name)["end_s"])


def load_golden(scenario_name: str) -> dict:
    with np.load(GOLDEN_DIR / f"{scenario_name}.npz") as data:
        return {key: data[key] for key in data.files}


def logged(golden: dict) -> dict:
    """The fixture's log: {signal: samples}, without ``t``."""
    return {key[len("log/"):]: value for key, value in golden.items()
            if key.startswith("log/") and key != "log/t"}


def scale(expected) -> np.ndarray:
    """Each column's scale: its largest finite magnitude in the fixture (1
    for a column that is 0 throughout)."""
    column = np.abs(np.asarray(expected, dtype=float)).reshape(len(expected), -1)
    peak = np.max(np.where(np.isfinite(column), column, 0.0), axis=0)
    return np.where(peak > 0, peak, 1.0)


def relative_deviation(actual, expected) -> np.ndarray:
    """|actual - expected| / scale, per sample and column (0 where both are
    NaN, inf where only one is)."""
    actual = np.asarray(actual, dtype=float).reshape(len(expected), -1)
    expected = np.asarray(expected, dtype=float).reshape(len(expected), -1)
    both_nan = np.isnan(actual) & np.isnan(expected)
    with np.errstate(invalid="ignore"):
        deviation = np.abs(actual - expected) / scale(expected)
    deviation[both_nan] = 0.0
    deviation[np.isnan(deviation)] = np.inf
    return deviation


# ---------------------------------------------------------------- recording


def perturbed_logs(scenario_name: str, end_s: float):
    """{run name: log} of the sensitivity runs, cut as the fixture is."""
    runs = {}
    for name, run in SENSITIVITY_RUNS.items():
        override = perturbation_override(scenario_name, *run)
        runs[name] = select(simulate_log(scenario_name, end_s, [override]), end_s)
    own = openblas_core()
    for core in KERNEL_RUNS:
        if core != own:
            log = kernel_log(scenario_name, end_s, core)
            if log is not None:
                runs[f"openblas_{core}"] = log
    return runs


def perturbation_override(scenario_name: str, kind: str, joint: int, factor: float) -> str:
    """The ``--set`` override of a sensitivity run: the scenario's faults
    and one more, of ``kind`` on ``joint`` with magnitude ``factor``, from
    the first contact to the end."""
    from drake_contact import load_scenario
    faults = [dc.asdict(f) for f in load_scenario(scenario_name).faults]
    faults.append({"kind": kind, "joint": joint, "magnitude": factor, "start_from": "contact",
                   "start_s": 0.0, "duration_s": float("inf")})
    return "faults=" + json.dumps(faults).replace("Infinity", ".inf")


def kernel_log(scenario_name: str, end_s: float, core: str):
    """The fixture's cut of a run under another OpenBLAS core (a
    subprocess); None if this CPU cannot run that core's kernels."""
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "log.npz"
        probe = subprocess.run(
            [sys.executable, "-c", "import numpy; numpy.ones((64, 64)) @ numpy.ones((64, 64))"],
            env=dict(os.environ, OPENBLAS_CORETYPE=core), capture_output=True)
        if probe.returncode != 0:
            return None
        subprocess.run([sys.executable, __file__, "--log", scenario_name, repr(end_s), str(out)],
                       env=dict(os.environ, OPENBLAS_CORETYPE=core), check=True)
        with np.load(out) as data:
            return {key: data[key] for key in data.files}


def sensitivity(scenario_name: str, base: dict, end_s: float):
    """({signal: largest relative deviation of any sensitivity run from
    ``base``, per sample and column}, [run names])."""
    runs = perturbed_logs(scenario_name, end_s)
    envelope = {}
    for signal, expected in base.items():
        if signal == "t":
            continue
        columns = np.asarray(expected).reshape(len(expected), -1).shape[1]
        deviation = np.zeros((len(expected), columns))
        for log in runs.values():
            # fault_active: the sensitivity run's own fault adds a column.
            actual = np.asarray(log[signal]).reshape(len(expected), -1)
            actual = actual[:, :deviation.shape[1]]
            deviation = np.maximum(deviation, relative_deviation(actual, expected))
        envelope[signal] = np.minimum(deviation, np.finfo(np.float32).max).astype(np.float32)
    return envelope, sorted(runs)


def _write(scenario_name: str, golden: dict):
    np.savez_compressed(GOLDEN_DIR / f"{scenario_name}.npz", **golden)


def record(scenario_name: str) -> Path:
    """Records a fixture: the log, then its sensitivity (a change of physics)."""
    if scenario_name in FIXED_END_S:
        end_s = FIXED_END_S[scenario_name]
    else:
        probe = simulate_log(scenario_name, 12.0)
        switch = probe["t"][int(np.argmax(probe["mode"] > 0))]
        assert probe["mode"].max() > 0, f"{scenario_name}: no contact switch by 12 s"
        end_s = round(float(switch) + AFTER_SWITCH_S, 3)
    log = select(simulate_log(scenario_name, end_s), end_s)
    GOLDEN_DIR.mkdir(exist_ok=True)
    golden = {f"log/{k}": v for k, v in log.items()}
    golden |= {"end_s": np.float64(end_s), "versions": json.dumps(versions())}
    _write(scenario_name, golden)
    return add_sensitivity(scenario_name, base=log)


def add_sensitivity(scenario_name: str, base=None) -> Path:
    """Measures the fixture's sensitivity to rounding around this machine's
    own run (``base``, run here when not given) and stores it beside the
    fixture's log, which is left as it is."""
    golden = load_golden(scenario_name)
    end_s = float(golden["end_s"])
    if base is None:
        base = select(simulate_log(scenario_name, end_s), end_s)
    envelope, runs = sensitivity(scenario_name, base, end_s)
    golden = {k: v for k, v in golden.items() if not k.startswith("sensitivity")}
    golden |= {f"sensitivity/{k}": v for k, v in envelope.items()}
    golden["sensitivity_runs"] = json.dumps({"runs": runs, "machine": versions()})
    _write(scenario_name, golden)
    return GOLDEN_DIR / f"{scenario_name}.npz"


# --------------------------------------------------------------- comparison


@dc.dataclass
class SignalCheck:
    """One signal of a run against its fixture."""

    signal: str
    # Largest deviation as a fraction of its allowance (> 1: fails).
    worst: float
    # Where that is (s), and the largest deviation relative to the scale.
    worst_t: float
    deviation: float
    # Samples of a quantized signal one quantum off after the switch, and
    # how many may be.
    quantum_steps: int = 0
    quantum_steps_allowed: int = 0
    # Bit for bit equal to the fixture.
    identical: bool = False


def allowance(golden: dict, signal: str) -> np.ndarray:
    """Per sample and column, the largest relative deviation allowed."""
    t = golden["log/t"]
    measured = golden.get(f"sensitivity/{signal}")
    if measured is None:
        raise KeyError(f"the fixture has no sensitivity for '{signal}': run "
                       "python tests/golden_logs.py --sensitivity")
    grown = np.maximum.accumulate(measured.astype(float), axis=0)
    ahead = np.searchsorted(t, t + LEAD_S, side="right") - 1
    return np.maximum(MARGIN * grown[ahead], FLOOR)


def switch_index(mode) -> int:
    """The first sample in contact mode, -1 if none."""
    mode = np.asarray(mode)
    return int(np.argmax(mode > 0)) if np.any(mode > 0) else -1


def quantum(expected) -> np.ndarray:
    """Each column's quantum: its smallest step between distinct values (inf
    for a constant column)."""
    columns = np.asarray(expected, dtype=float).reshape(len(expected), -1)
    steps = []
    for column in columns.T:
        values = np.unique(column[np.isfinite(column)])
        steps.append(np.min(np.diff(values)) if len(values) > 1 else np.inf)
    return np.array(steps)


def check_signal(golden: dict, signal: str, actual, switch: int) -> SignalCheck:
    """A signal against its fixture (see the module's docstring)."""
    expected = golden[f"log/{signal}"]
    t = golden["log/t"]
    identical = bool(np.array_equal(actual, expected, equal_nan=True))
    deviation = relative_deviation(actual, expected)
    ratio = deviation / allowance(golden, signal)
    steps = allowed = 0
    if signal in QUANTIZED and switch >= 0:
        step = quantum(expected) / scale(expected)
        one_step = (deviation > 0) & (deviation <= step * (1 + 1e-9))
        one_step[:switch] = False
        steps = int(one_step.any(axis=1).sum())
        allowed = int(QUANTIZED_FRACTION * (len(t) - switch))
        ratio = np.where(one_step, 0.0, ratio)
    row, column = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
    return SignalCheck(signal, float(ratio[row, column]), float(t[row]),
                       float(deviation[row, column]), steps, allowed, identical)


def check(scenario_name: str, log: dict, golden=None):
    """(checks, problems): a :class:`SignalCheck` per signal of the fixture,
    and one line per way in which ``log`` (cut as the fixture is) fails it."""
    golden = load_golden(scenario_name) if golden is None else golden
    problems, checks = [], []
    expected_switch = switch_index(golden["log/mode"]) if "log/mode" in golden else -1
    if "log/mode" in golden:
        switch = switch_index(log["mode"]) if "mode" in log else -2
        if switch != expected_switch:
            t = golden["log/t"]
            problems.append(f"{scenario_name}: the contact switch moved from sample "
                            f"{expected_switch} (t = {t[expected_switch]:.3f} s) to {switch}")
    for signal, expected in logged(golden).items():
        if signal not in log:
            problems.append(f"{scenario_name}: the log lost '{signal}'")
            continue
        actual = np.asarray(log[signal])
        if actual.shape != expected.shape:
            problems.append(f"{scenario_name}: '{signal}' has shape {actual.shape}, "
                            f"the fixture {expected.shape}")
            continue
        result = check_signal(golden, signal, actual, expected_switch)
        checks.append(result)
        if result.worst > 1.0:
            problems.append(
                f"{scenario_name}: '{signal}' differs from the golden log by "
                f"{result.deviation:.3g} of its scale at t = {result.worst_t:.3f} s, "
                f"{result.worst:.3g} times its allowance (MARGIN x the measured "
                "rounding sensitivity)")
        if result.quantum_steps > result.quantum_steps_allowed:
            problems.append(
                f"{scenario_name}: '{signal}' is one quantum off on {result.quantum_steps} "
                f"samples after the switch (at most {result.quantum_steps_allowed})")
    return sorted(checks, key=lambda c: -c.worst), problems


#: What --compare calls guarded tightly: every signal's allowance within
#: this fraction of its scale.
TIGHT = 1e-3


def tight_until(golden: dict):
    """The last sample time up to which every signal's allowance is within
    TIGHT of its scale (the sensitivity runs themselves may diverge late in
    the window, a count flipped or a stick-slip fallen elsewhere; from then
    on that signal is guarded only loosely)."""
    t = golden["log/t"]
    loose = np.zeros(len(t), bool)
    for signal in logged(golden):
        loose |= (allowance(golden, signal) > TIGHT).any(axis=1)
    return float(t[-1]) if not loose.any() else float(t[max(int(np.argmax(loose)) - 1, 0)])


def report(scenario_name: str, checks, problems, golden=None) -> str:
    """The ``--compare`` lines of one scenario."""
    if checks and all(c.identical for c in checks) and not problems:
        return f"{scenario_name}: bit-identical to the fixture"
    worst = checks[0] if checks else None
    head = (f"{scenario_name}: {'FAILS' if problems else 'passes'}; largest deviation "
            f"{worst.worst:.3g} of its allowance ('{worst.signal}' at t = {worst.worst_t:.3f} s, "
            f"{worst.deviation:.2e} of scale)" if worst else f"{scenario_name}: no signals")
    moved = [c for c in checks if not c.identical]
    lines = [head, f"  {len(moved)} of {len(checks)} signals moved"]
    if golden is not None:
        end = float(golden["log/t"][-1])
        until = tight_until(golden)
        lines.append(f"  every allowance within {TIGHT:g} of scale " + (
            "to the end" if until == end else f"until t = {until:.3f} s (end {end:.3f} s)"))
    lines += [f"  {c.signal:32s} {c.worst:9.2e} of allowance, {c.deviation:9.2e} of scale"
              + (f", {c.quantum_steps} one-quantum samples" if c.quantum_steps else "")
              for c in moved[:8]]
    return "\n".join(lines + [f"  {p}" for p in problems])


def _main(args):
    from drake_contact.resources import bundled_scenario_names
    if args and args[0] == "--log":
        name, end_s, out = args[1], float(args[2]), args[3]
        np.savez(out, **select(simulate_log(name, end_s), end_s))
        return 0
    if args and args[0] == "--compare":
        failed = 0
        for name in args[1:] or bundled_scenario_names():
            golden = load_golden(name)
            checks, problems = check(name, golden_log(name), golden)
            failed += bool(problems)
            print(report(name, checks, problems, golden), flush=True)
        return 1 if failed else 0
    if args and args[0] == "--sensitivity":
        for name in args[1:] or bundled_scenario_names():
            add_sensitivity(name)
            print(f"{name}: sensitivity added", flush=True)
        return 0
    for name in args or bundled_scenario_names():
        path = record(name)
        print(f"{name}: {path.stat().st_size / 1e3:.0f} kB, end {golden_end_s(name):.3f} s")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    sys.exit(_main(sys.argv[1:]))
