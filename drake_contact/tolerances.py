"""Tolerances on times and on ratios of times, named once.

This module imports nothing, so that the application's processes that only
start and score runs can use them without loading pydrake.
"""

#: Two times (s) closer than this are one instant. Sample times are whole
#: multiples of the 1 ms control period, which sums of floats reach only
#: within a few ulps, so comparisons with a sample time (a window's edge, a
#: hold's end, a fault's start) allow this much either way.
TIME_TOLERANCE_S = 1e-9

#: A ratio of two durations closer than this to a whole number is that
#: number (windows in a span, cycles of a schedule, plant steps per sample).
RATIO_TOLERANCE = 1e-9
