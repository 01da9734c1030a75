"""Named tolerances of the planner: what each small number protects.

Lengths are mm, filament mm, joints their own units (rad or mm); a relative tolerance is a
fraction of the value it compares. Those the whole package shares come from deltaslice/tolerances.py.
"""

from ..tolerances import JOINT_ROUNDOFF, SAME_LENGTH

# mm: a move, step or lift shorter than this does not move the tool (zero-length moves,
# repeated points); well under any machine's resolution and far above rounding of mm-sized sums.
NO_MOTION = SAME_LENGTH
# mm of filament: a prime (the filament pushed or pulled before the first working move) smaller
# than this is rounding of a sum of retracts and unretracts that cancel, not a move.
NO_FILAMENT = 1e-12
# mm: a grid point's side "before" it (the piece that ends there) is located this far back, so a
# line/arc join sees the feed of both pieces it joins.
ARC_SIDE = 1e-9
# relative: a start speed within this of the fastest the next window can take is that speed (the
# solver's rounding), not one it must refuse.
SAME_SPEED = 1e-9
# joint units: a joint this close outside its range is at its end (the inverse kinematics'
# rounding), not beyond it, when an unreachable point is explained.
JOINT_RANGE = JOINT_ROUNDOFF
# mm: grid points closer than this are one (nothing between them but ill-conditioned stages).
GRID_POINT = 1e-7
# relative: a unit vector's dot product with the next below 1 - this turns (a new piece).
STRAIGHT = 1e-9
# s or mm/s: the floor under a denominator that may be zero (a stage of no time, a move at rest).
DIVISION_FLOOR = 1e-12
# mm: a sampled tool point this far below a travel's lowest allowed height still clears it
# (the forward kinematics' rounding).
CLEARANCE = 1e-6
# relative: a move's sampled top speed within this of the feed keeps to it; a stretch in time
# adds RETIME more, so the same path's rounded time falls on the slow side.
FEED_MATCH = 1e-6
RETIME = 1e-5
# s: a duration within this of a whole number of output periods gives no sample past its end.
SAMPLE_TIME = 1e-9
# the scale the safe trapezoid planner stops shrinking at: a machine that needs less moves nowhere.
SMALLEST_SCALE = 1e-8
# mm: a blended piece (corner arc or straight stretch) no longer than this has no length, and
# no direction: it is left out of the path.
ZERO_LENGTH = 1e-12
# mm^2: the floor under a squared length divided by (a corner whose two neighbours coincide),
# the smallest that keeps the quotient finite without moving any real value.
SQUARED_FLOOR = 1e-300
# relative: in the compiled solver, two bounds that cross by less than this of their size are
# rounding (the stage's interval is a point), and an empty pairing needs more than this.
BOUND_ROUNDING = 1e-9
PAIR_ROUNDING = 1e-12
