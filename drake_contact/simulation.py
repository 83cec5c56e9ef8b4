"""Simulating a contact diagram: the run's logs, its divergence checks and
its metrics.

Building is separate from running. :func:`MakeContactDiagram` builds the
station; :func:`AddSignalLoggers` logs every signal it exports (one logger); the
user may add systems and loggers of their own; :func:`simulate` then runs
any diagram holding a station and its :class:`SignalLoggers`, with the
divergence checks, and returns a :class:`RunResult` (logs, metrics, status).
:func:`simulate_scenario` does all of that for one scenario. A run that
diverges (non-finite state, or a contact force above
``simulation.force_limit``) or is interrupted (Ctrl-C) keeps its logs up to
the last logged sample; its metrics say why it stopped.
"""

import dataclasses as dc
import os
import shutil
import time
import zipfile
from collections.abc import Mapping
from pathlib import Path

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput, Multiplexer, VectorLogSink

from drake_contact.diagram import (
    ContactStation, MakeContactDiagram, MakeEnsembleDiagram, SeedNoise)
from drake_contact.errors import ScenarioError, SimulationDiverged
from drake_contact.plant.arm import CONTROL_PERIOD, RATIO_TOLERANCE
from drake_contact.scenario import Scenario
from drake_contact.scoring.metrics import add_stiffness_ratio, compute_metrics
from drake_contact.visualization import (
    AddContactVisualization, check_record_path, finish_recording, new_meshcat, start_recording)

#: Simulated seconds between divergence checks and progress reports.
CHUNK_S = 0.1


@dc.dataclass
class RunResult:
    """What :func:`simulate` and :func:`run` return."""

    # 1 kHz logs by key (see ContactStation.signals), plus "t" (s).
    log: dict
    # compute_metrics(...) of the log, with "status" and "message".
    metrics: dict
    # "completed", "diverged" or "interrupted".
    status: str
    # Why it stopped, if it did not complete.
    message: str = ""
    # Wall-clock time of the simulation alone (s).
    wall_s: float = 0.0
    # The Simulator, to read the context (e.g. the user's own loggers'
    # FindLog(result.simulator.get_context())).
    simulator: Simulator | None = dc.field(default=None, repr=False, compare=False)


#: A spooled log holds at most this many samples in memory (10 s at 1 kHz,
#: about 5 MB for the neural run's 61 columns); the rest is on disk.
SPOOL_BUFFER_SAMPLES = 10_000


class SpooledLog(Mapping):
    """A run's log on disk, read column by column: ``log[key]`` reads that
    key's samples from its file (a new array each time; nothing is held), so
    what a reader holds at once is what it asked for. The files are the raw
    float64 samples of each key, in :class:`SignalLoggers` ``spool``'s
    folder. The values are the very numbers an in-memory log holds."""

    def __init__(self, folder: Path, shapes: dict, samples: int):
        self.folder = Path(folder)
        # key -> (file name, shape of one sample: () or (width,))
        self._shapes = dict(shapes)
        self.samples = samples

    def __getitem__(self, key):
        name, shape = self._shapes[key]
        width = int(np.prod(shape)) if shape else 1
        data = np.fromfile(self.folder / name, dtype="<f8", count=self.samples * width)
        return data.reshape((self.samples,) + tuple(shape))

    def __setitem__(self, key, value):
        """Adds (or replaces) a key of ``samples`` rows, written to disk."""
        value = np.ascontiguousarray(value, dtype="<f8")
        if len(value) != self.samples:
            raise ValueError(f"{key}: {len(value)} samples, the log has {self.samples}")
        name = self._shapes.get(key, (f"{key}.f8",))[0]
        value.tofile(self.folder / name)
        self._shapes[key] = (name, value.shape[1:])

    def __iter__(self):
        return iter(self._shapes)

    def __len__(self):
        return len(self._shapes)

    def truncated(self, samples: int) -> "SpooledLog":
        """The same files read only up to ``samples`` samples."""
        return SpooledLog(self.folder, self._shapes, min(samples, self.samples))


class NpzLog(Mapping):
    """A ``log.npz`` read key by key (each ``log[key]`` reads that array from
    the file), for the log :func:`run` returns after it wrote the file."""

    def __init__(self, path):
        self.path = Path(path)
        with np.load(self.path) as npz:
            self._keys = list(npz.keys())

    def __getitem__(self, key):
        if key not in self._keys:
            raise KeyError(key)
        with np.load(self.path) as npz:
            return npz[key]

    def __iter__(self):
        return iter(self._keys)

    def __len__(self):
        return len(self._keys)


def save_log(path, log: Mapping):
    """Writes ``log`` (any mapping of arrays) as an uncompressed ``.npz``
    that ``np.load`` reads, one key at a time: a spooled log is never held in
    memory whole (``np.savez(**log)`` would read every key first)."""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED, allowZip64=True) as archive:
        for key in log:
            array = np.asanyarray(log[key])
            with archive.open(f"{key}.npy", "w", force_zip64=True) as member:
                np.lib.format.write_array(member, array, allow_pickle=False)
            del array


@dc.dataclass
class SignalLoggers:
    """The logger :func:`AddSignalLoggers` added: every logged signal of the
    station through one Multiplexer into one 1 kHz ``VectorLogSink`` (one
    publish per sample, not one per signal), and the column of each signal
    in it.

    :meth:`drain` moves the samples logged so far out of Drake's log (which
    it clears) into one array allocated once for the whole run, so a long
    run holds each sample once; :meth:`collect` drains and returns the log
    dict, whose arrays are views of that array.

    With ``spool`` (a folder; :func:`run` sets its run folder's
    ``.log_spool``) the array holds at most SPOOL_BUFFER_SAMPLES samples:
    :meth:`flush` appends them to one file per log key there, and
    :meth:`collect` returns a :class:`SpooledLog` reading those files. A run
    of any length then holds a few MB of log (a 600 s neural run stays
    under 300 MB resident)."""

    station: ContactStation
    # The VectorLogSink of all logged signals, in ``columns`` order.
    sink: VectorLogSink
    # Exported port name -> its columns (a slice) in the sink's vector.
    columns: dict
    # A folder to spool the log to (None: the log stays in memory).
    spool: Path | None = None
    # Samples drained so far and not flushed: times, and an (n, all columns) array.
    _times: np.ndarray = dc.field(default_factory=lambda: np.empty(0), repr=False)
    _buffer: np.ndarray = dc.field(default_factory=lambda: np.empty((0, 0)), repr=False)
    _n: int = 0
    # Samples flushed to the spool files.
    _flushed: int = 0

    def reserve(self, samples: int):
        """Allocates room for ``samples`` samples of every signal (with a
        spool, at most SPOOL_BUFFER_SAMPLES)."""
        if self.spool is not None:
            samples = min(samples, SPOOL_BUFFER_SAMPLES)
        self._grow(samples)

    def _grow(self, samples: int):
        if samples > len(self._times):
            width = self.sink.get_input_port().size()
            self._times = np.resize(self._times, samples)
            old = self._buffer
            self._buffer = np.empty((samples, width))
            if self._n:
                self._buffer[:self._n] = old[:self._n]

    def drain(self, context):
        """Moves the new samples at ``context`` into the array (growing it,
        or with a spool flushing it first, if needed) and clears Drake's log."""
        log = self.sink.FindMutableLog(context)
        k = log.num_samples()
        if k == 0:
            return
        if self.spool is not None and self._n + k > len(self._times):
            self.flush()
        end = self._n + k
        if end > len(self._times):
            # In memory: double. Spooled: what this drain brings, if more.
            self._grow(end if self.spool is not None else max(end, 2 * len(self._times)))
        self._times[self._n:end] = log.sample_times()
        self._buffer[self._n:end] = log.data().T
        log.Clear()
        self._n = end

    def _spool_keys(self):
        """(key, (sink columns, part) or None for ``t``, file name, shape of
        one sample) of every log key, ``t`` first."""
        yield "t", None, "t.f8", ()
        for name, columns in self.columns.items():
            width = columns.stop - columns.start
            for key, part in self.station.signals[name].log_as.items():
                shape = () if isinstance(part, int) else (len(range(width)[part]),)
                yield key, (columns, part), f"{key}.f8", shape

    def flush(self):
        """Appends the samples held in memory to the spool's files (no-op
        without a spool)."""
        if self.spool is None:
            return
        if self._flushed == 0:
            self.spool.mkdir(parents=True, exist_ok=True)
        n = self._n
        for _, where, name, _ in self._spool_keys():
            if where is None:
                data = self._times[:n]
            else:
                columns, part = where
                data = self._buffer[:n, columns][:, part]
            with open(self.spool / name, "ab" if self._flushed else "wb") as f:
                f.write(np.ascontiguousarray(data, dtype="<f8").tobytes())
        self._flushed += n
        self._n = 0

    def log_rate(self):
        """(columns with ``t``, bytes per simulated second) of the log."""
        columns = self.sink.get_input_port().size() + 1
        return columns, columns * 8 / CONTROL_PERIOD

    def check_spool_space(self, duration: float):
        """Raises ScenarioError, naming simulation.duration and its limit,
        when the spool's disk cannot hold a run of ``duration`` s."""
        columns, bytes_per_s = self.log_rate()
        folder = self.spool
        while not folder.exists():
            folder = folder.parent
        free = shutil.disk_usage(folder).free
        limit_s = 0.9 * free / bytes_per_s
        if duration > limit_s:
            raise ScenarioError(
                f"simulation.duration = {duration:g} is out of range: its 1 kHz logs ({columns} "
                f"columns) would need {duration * bytes_per_s / 1e9:.3g} GB on disk; "
                f"{folder} has room for at most {limit_s:.0f} s")

    def latest(self, name, samples, env=0):
        """(times, (samples, size) array) of environment ``env``'s signal
        ``name``, its last ``samples`` drained (with a spool, at most those
        since the last flush)."""
        start = max(self._n - samples, 0)
        return self._times[start:self._n], self._buffer[start:self._n, self.env_columns(name, env)]

    def env_columns(self, name, env):
        """The columns of environment ``env``'s signal ``name`` in the sink
        (an ensemble's signal holds its environments side by side)."""
        size = self.station.signals[name].size
        start = self.columns[name].start + env * size
        return slice(start, start + size)

    def collect(self, context, env=0) -> Mapping:
        """The log at ``context`` of environment ``env``: ``t`` and every
        log key (a dict of views of the array; with a spool, a
        :class:`SpooledLog`)."""
        self.drain(context)
        if self.spool is not None:
            self.flush()
            shapes = {key: (name, shape) for key, _, name, shape in self._spool_keys()}
            out = SpooledLog(self.spool, shapes, self._flushed)
        else:
            n = self._n
            out = {"t": self._times[:n]}
            for name in self.columns:
                signal = self._buffer[:n, self.env_columns(name, env)]
                for key, part in self.station.signals[name].log_as.items():
                    out[key] = signal[:, part]
        add_stiffness_ratio(out)
        return out


def AddSignalLoggers(builder: DiagramBuilder, station: ContactStation) -> SignalLoggers:
    """Adds a 1 kHz logger (``log_signals``, fed by the Multiplexer
    ``log_signals_mux``) of every logged signal of ``station``, which must
    be in ``builder``; returns it."""
    names = [name for name, signal in station.signals.items() if signal.log_as]
    sizes = [station.signals[name].size * station.num_envs for name in names]
    mux = builder.AddNamedSystem("log_signals_mux", Multiplexer(sizes))
    for index, name in enumerate(names):
        builder.Connect(station.GetOutputPort(name), mux.get_input_port(index))
    sink = LogVectorOutput(mux.get_output_port(), builder, CONTROL_PERIOD)
    sink.set_name("log_signals")
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    columns = {name: slice(int(offsets[i]), int(offsets[i + 1])) for i, name in enumerate(names)}
    return SignalLoggers(station, sink, columns)


def MakeRunDiagram(scenario: Scenario, *, meshcat=None):
    """The station of ``scenario`` with its loggers and, given a
    ``meshcat``, the arm, wall and force drawn there. Returns (diagram,
    loggers)."""
    builder = DiagramBuilder()
    station = builder.AddSystem(MakeContactDiagram(scenario))
    loggers = AddSignalLoggers(builder, station)
    if meshcat is not None:
        AddContactVisualization(builder, station, meshcat)
    diagram = builder.Build()
    diagram.set_name("run")
    return diagram, loggers


#: The logs may take at most this share of the machine's memory.
LOG_MEMORY_SHARE = 0.5


def check_logs_fit(loggers: SignalLoggers, duration: float):
    """Raises ScenarioError, naming simulation.duration and its limit on
    this machine, when the run's 1 kHz logs would not fit in
    LOG_MEMORY_SHARE of the physical memory (they are held in memory)."""
    columns, bytes_per_s = loggers.log_rate()
    memory = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    limit_s = LOG_MEMORY_SHARE * memory / bytes_per_s
    if duration > limit_s:
        raise ScenarioError(
            f"simulation.duration = {duration:g} is out of range: its 1 kHz logs ({columns} "
            f"columns) would need {duration * bytes_per_s / 1e9:.3g} GB; this machine allows "
            f"at most {limit_s:.0f} s (half of its {memory / 2**30:.0f} GiB of memory)")


def simulate(diagram, loggers: SignalLoggers, *, progress=None, realtime_rate=0.0,
             meshcat=None, record=None, live=True) -> RunResult:
    """Simulates ``diagram`` (holding ``loggers.station``) for the station's
    ``simulation.duration``, seeded by :func:`SeedNoise`; returns a RunResult.

    The run stops at the first non-finite state or contact force above
    ``simulation.force_limit`` (status "diverged", the logs kept up to
    that sample) and on Ctrl-C ("interrupted"). ``progress(t, duration,
    wall_s)`` is called after every chunk of CHUNK_S. ``realtime_rate`` > 0
    paces the run (simulated s per wall s). ``meshcat``: record the
    diagram's Meshcat visualizers and send the recording there at the end
    (``live``: also each frame as it is drawn); ``record``: also write it
    as a standalone HTML playback to this file.
    """
    scenario = loggers.station.scenario
    if loggers.spool is not None:
        loggers.check_spool_space(scenario.simulation.duration)
    else:
        check_logs_fit(loggers, scenario.simulation.duration)
    duration = scenario.simulation.duration
    simulator, context = _seeded_simulator(diagram, loggers, duration)
    simulator.set_target_realtime_rate(realtime_rate)
    visualizers = start_recording(diagram, live=live) if meshcat is not None else []
    force_limit = scenario.simulation.force_limit
    status, message = "completed", ""
    start = time.perf_counter()
    try:
        for t in advance_in_chunks(simulator, context, loggers, duration):
            _check_divergence(loggers, force_limit)
            if progress is not None:
                progress(t, duration, time.perf_counter() - start)
    except SimulationDiverged as e:
        status, message = "diverged", str(e)
    except KeyboardInterrupt:
        status, message = "interrupted", f"interrupted at t = {context.get_time():.3f} s"
    except RuntimeError as e:
        if not drake_raised(e):
            raise
        status = "diverged"
        # Drake's own checks (e.g. a NaN reaching the plant's applied-force
        # input) say where; the time is the simulator's.
        message = f"diverged at t = {context.get_time():.3f} s: {str(e).splitlines()[0]}"
    wall_s = time.perf_counter() - start
    if meshcat is not None:
        finish_recording(visualizers, meshcat, record)
    return _result(scenario, loggers.collect(context), status, message, wall_s, simulator)


def _seeded_simulator(diagram, loggers, duration):
    """A Simulator of ``diagram`` with its stations' noise seeded
    (:func:`SeedNoise`) and the logs' room for ``duration``; returns it and
    its context."""
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    SeedNoise(diagram, context)
    loggers.reserve(int(round(duration / CONTROL_PERIOD)) + 1)
    return simulator, context


def drake_raised(error: RuntimeError) -> bool:
    """Whether ``error`` is one of Drake's own (its C++ checks, e.g. a NaN
    reaching the plant: a divergence) rather than raised by Python code the
    simulator called back (a system's update, a plug-in's bug: a failure).
    Drake's reach Python at the simulator's call in this module; a Python
    callback's keep its own frames, deeper, in its traceback."""
    tb = error.__traceback__
    while tb is not None and tb.tb_next is not None:
        tb = tb.tb_next
    return tb is None or tb.tb_frame.f_code.co_filename == __file__


def advance_in_chunks(simulator, context, loggers, duration):
    """Initializes ``simulator`` and advances it to ``duration`` in chunks
    of CHUNK_S (whole multiples of it, no accumulated rounding, ending
    exactly at the duration), draining the logs after each; yields each
    chunk's end time."""
    simulator.Initialize()
    chunks = int(np.ceil(duration / CHUNK_S - RATIO_TOLERANCE))
    for k in range(1, chunks + 1):
        t = duration if k == chunks else k * CHUNK_S
        simulator.AdvanceTo(t)
        loggers.drain(context)
        yield t


def _result(scenario, log, status, message, wall_s, simulator) -> RunResult:
    """The RunResult of a run that ended with ``status``: its log (cut at
    the first bad sample of a diverged run) and metrics."""
    if status == "diverged":
        log = _truncate_at_divergence(log, scenario.simulation.force_limit)
    metrics = compute_metrics(scenario, log, wall_s)
    metrics["status"] = status
    if "ended_safe_log" in metrics:
        metrics["ended_safe"] = status == "completed" and metrics.pop("ended_safe_log")
    if message:
        metrics["message"] = message
    return RunResult(log=log, metrics=metrics, status=status, message=message, wall_s=wall_s,
                     simulator=simulator)


def simulate_scenario(scenario: Scenario, *, progress=None, meshcat=None, record=None,
                      realtime_rate=0.0, spool=None) -> RunResult:
    """Builds :func:`MakeRunDiagram` and simulates it. ``meshcat``: show the
    run live there (arm, wall, contact force). ``record``: write a standalone
    HTML playback to this file (checked before simulating; a headless
    Meshcat is made if none is given), also for a diverged or interrupted
    run. Without ``meshcat`` and ``record`` nothing is drawn. ``spool``: a
    folder to stream the log to (see :class:`SignalLoggers`)."""
    live = meshcat is not None
    if record is not None:
        record = check_record_path(record)
        meshcat = meshcat or new_meshcat()
    diagram, loggers = MakeRunDiagram(scenario, meshcat=meshcat)
    loggers.spool = None if spool is None else Path(spool)
    return simulate(diagram, loggers, progress=progress, realtime_rate=realtime_rate,
                    meshcat=meshcat, record=record, live=live)


def MakeEnsembleRunDiagram(scenarios):
    """The ensemble station of ``scenarios`` (:func:`MakeEnsembleDiagram`)
    with its loggers. Returns (diagram, loggers)."""
    builder = DiagramBuilder()
    station = builder.AddSystem(MakeEnsembleDiagram(scenarios))
    loggers = AddSignalLoggers(builder, station)
    diagram = builder.Build()
    diagram.set_name("run")
    return diagram, loggers


def simulate_ensemble(scenarios, *, progress=None) -> list:
    """Simulates the environments of ``scenarios`` in one ensemble diagram,
    each seeded with its own ``simulation.seed``, for the longest
    ``simulation.duration``; returns a RunResult per environment, its log
    cut at its own duration: bit for bit the log :func:`simulate_scenario`
    gives alone.

    An environment that diverges (a non-finite state, or a contact force
    above its ``simulation.force_limit``) is reported as diverged at its
    first bad sample, its log kept up to that sample, while the others run
    on. ``progress(t, duration, wall_s)`` is called after every chunk of
    CHUNK_S. ``wall_s`` of each result is the ensemble's wall time divided
    by the number of environments."""
    diagram, loggers = MakeEnsembleRunDiagram(scenarios)
    duration = max(s.simulation.duration for s in scenarios)
    check_logs_fit(loggers, duration)
    simulator, context = _seeded_simulator(diagram, loggers, duration)
    running = set(range(len(scenarios)))
    stopped = {}
    start = time.perf_counter()
    try:
        for t in advance_in_chunks(simulator, context, loggers, duration):
            for env in sorted(running):
                try:
                    _check_divergence(loggers, scenarios[env].simulation.force_limit, env)
                except SimulationDiverged as e:
                    stopped[env] = ("diverged", str(e))
                    running.discard(env)
            if progress is not None:
                progress(t, duration, time.perf_counter() - start)
    except KeyboardInterrupt:
        for env in running:
            stopped[env] = ("interrupted", f"interrupted at t = {context.get_time():.3f} s")
    except RuntimeError as e:
        if not drake_raised(e):
            raise
        for env in running:
            stopped[env] = ("diverged", f"diverged at t = {context.get_time():.3f} s: "
                                        f"{str(e).splitlines()[0]}")
    wall_s = (time.perf_counter() - start) / len(scenarios)
    results = []
    for env, scenario in enumerate(scenarios):
        log = loggers.collect(context, env)
        samples = int(round(scenario.simulation.duration / CONTROL_PERIOD)) + 1
        log = {key: value[:samples] for key, value in log.items()}
        status, message = stopped.get(env, ("completed", ""))
        results.append(_result(scenario, log, status, message, wall_s, simulator))
    return results


def _check_divergence(loggers: SignalLoggers, force_limit, env=0):
    """Raises SimulationDiverged at the first bad sample of the last chunk
    (of environment ``env``)."""
    chunk = int(round(CHUNK_S / CONTROL_PERIOD)) + 1
    times, state = loggers.latest("joint_state_true", chunk, env)
    state = state.T
    force = loggers.latest("contact_force_true", chunk, env)[1][:, 0]
    bad_state = ~np.all(np.isfinite(state), axis=0)
    if loggers.station.num_envs > 1:
        # An ensemble's plant gets 0 for a non-finite torque (FiniteGuard),
        # where a run alone stops.
        torque = loggers.latest("joint_torque_applied", chunk, env)[1].T
        bad_state |= ~np.all(np.isfinite(torque), axis=0)
    bad_force = ~np.isfinite(force) | (force > force_limit)
    if bad_state.any() or bad_force.any():
        i = int(np.argmax(bad_state | bad_force))
        if bad_state[i]:
            where = "joint_state_true"
            what = "the arm's state is not finite"
        elif not np.isfinite(force[i]):
            where = "contact_force_true"
            what = "the contact force is not finite"
        else:
            where = "contact_force_true"
            what = f"the contact force {force[i]:.4g} N exceeds simulation.force_limit = {force_limit} N"
        raise SimulationDiverged(
            f"diverged at t = {times[i]:.3f} s: {what} ({where})", time_s=times[i], where=where)


def _truncate_at_divergence(log, force_limit):
    """Keeps the samples up to and including the first bad one."""
    bad = ~np.isfinite(log["contact_force_true"]) | (log["contact_force_true"] > force_limit)
    bad |= ~np.all(np.isfinite(log["joint_positions_true"]), axis=1)
    if bad.any():
        stop = int(np.argmax(bad)) + 1
        if isinstance(log, SpooledLog):
            return log.truncated(stop)
        log = {k: v[:stop] for k, v in log.items()}
    return log
