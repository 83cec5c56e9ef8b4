"""Constants used across the package, named once.

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

#: The filtered force (N) above which the tip is in contact: the thesis's
#: switch from approach to hybrid control (section 4.4; its code's 0.8 N is
#: the `*_appendix_e` scenarios'). Every switch defaults to it, and the
#: faults' contact clock applies it to the true force.
CONTACT_THRESHOLD_N = 5.0
