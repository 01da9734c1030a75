"""Round-off allowances shared by the modules: what each one protects, named once.

Each is far below anything a machine resolves (a micron, a step, a sample) and far above the
round-off of the float arithmetic it guards (mm-scale coordinates, ratios of nearby numbers)."""

from __future__ import annotations

#: mm: two coordinates or lengths this close are the same point or no length at all.
SAME_LENGTH = 1e-9
#: s: the shortest span of time divided by (a file of one instant still has a rate).
SHORTEST_TIME = 1e-9
#: A ratio this close to an integer counts as that integer where it is rounded up or down into a
#: count (samples, loops, decimation): round-off must not add or drop one.
COUNT_ROUNDOFF = 1e-9
#: Relative round-off of a value compared with a bound computed from the same inputs.
RELATIVE_ROUNDOFF = 1e-9
#: rad or mm: a joint this far past its limit is there by round-off.
JOINT_ROUNDOFF = 1e-9
