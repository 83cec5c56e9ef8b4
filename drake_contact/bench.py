"""Speed: µs per simulated plant step of a scenario against the floor.

The floor is :func:`MakeFloorDiagram` (plant, wall and joint physics, no
sensors, estimator or controller): what any run of this arm costs. The ratio
scenario / floor says what the thesis's signal chain and controllers add.
Timings depend on the machine; this is a measurement, not a test.
"""

import time

from pydrake.systems.analysis import Simulator

from drake_contact.diagram import MakeFloorDiagram
from drake_contact.runner import simulate


def time_floor(scenario, duration):
    """µs per plant step of the floor diagram over ``duration`` s (best of 2)."""
    best = float("inf")
    for _ in range(2):
        simulator = Simulator(MakeFloorDiagram(scenario))
        simulator.Initialize()
        start = time.perf_counter()
        simulator.AdvanceTo(duration)
        best = min(best, time.perf_counter() - start)
    return best / (duration / scenario.arm.time_step) * 1e6


def time_scenario(scenario):
    """µs per plant step of a full run of ``scenario`` (logging included)."""
    log, status, message, wall_s = simulate(scenario)
    if status != "completed":
        raise RuntimeError(f"the benchmark run did not complete: {message}")
    return wall_s / (scenario.simulation.duration / scenario.arm.time_step) * 1e6


def bench(scenario, floor_duration=10.0, stream=print):
    """Times the floor and ``scenario`` in this process; returns the ratio."""
    floor_us = time_floor(scenario, floor_duration)
    stream(f"floor (plant, wall, joint physics): {floor_us:8.1f} us/step, "
           f"real-time factor {1e6 * scenario.arm.time_step / floor_us:6.2f}")
    run_us = time_scenario(scenario)
    stream(f"{scenario.description[:40]:<40}: {run_us:8.1f} us/step, "
           f"real-time factor {1e6 * scenario.arm.time_step / run_us:6.2f}")
    ratio = run_us / floor_us
    stream(f"ratio scenario / floor = {ratio:.2f}")
    return ratio
