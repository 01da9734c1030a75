"""The one exception family of deltaslice.

Every failure a user can cause (a bad printer file, a broken mesh, a point out of
reach, a corrupt stream) raises a subclass of :class:`DeltasliceError` whose
message says what is wrong and where. The CLI prints that message and exits
non-zero; no traceback reaches the user.
"""


class DeltasliceError(Exception):
    """Base class of every error deltaslice raises on purpose."""


class PrinterFileError(DeltasliceError):
    """A printer file is missing, unreadable or holds an invalid value."""


class MeshError(DeltasliceError):
    """A part file cannot be read, repaired or placed on the bed."""


class GcodeError(DeltasliceError):
    """A G-code file cannot be parsed."""


class UnreachableError(DeltasliceError):
    """A toolpath point lies outside the robot's reachable, non-singular volume."""


class PlanningError(DeltasliceError):
    """The planner could not find a trajectory within the limits."""


class StreamError(DeltasliceError):
    """A setpoint file or binary stream is corrupt, truncated or of the wrong kind."""


class SendError(DeltasliceError):
    """Sending a stream to a board failed: the port, a timeout, or the board's own error."""


class MeshWarning(UserWarning):
    """A mesh was sliced, but only after closing gaps or similar guesswork the user should hear about."""

class ToolpathWarning(UserWarning):
    """A toolpath was planned as given, but some of it looks like another unit or origin (metres
    for millimetres, mm/min for mm/s, heights below the bed)."""


class OutputError(DeltasliceError):
    """An output cannot be written: missing or read-only directory, the input itself, a full
    disk, or a job beyond the size and time bounds."""


class PlayError(DeltasliceError):
    """Playing a stream on a servo bus failed or was stopped (the laser is off by then);
    ``interrupted`` when Ctrl-C stopped it."""

    interrupted = False
