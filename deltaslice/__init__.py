"""deltaslice: a slicer-to-motion compiler for parallel-kinematics printers and engravers.

Pipeline (one module per stage, each returns a new object):

    part.stl --mesh--> Mesh --slicing--> Toolpath --planning--> Trajectory --emit--> file
"""

from .errors import (
    DeltasliceError,
    GcodeError,
    MeshError,
    PlanningError,
    PrinterFileError,
    StreamError,
    UnreachableError,
)
from .machine import Printer, load_printer
from .toolpath import Role, Toolpath

__version__ = "0.1.0"

__all__ = [
    "DeltasliceError",
    "GcodeError",
    "MeshError",
    "PlanningError",
    "PrinterFileError",
    "StreamError",
    "UnreachableError",
    "Printer",
    "load_printer",
    "Role",
    "Toolpath",
    "__version__",
]
