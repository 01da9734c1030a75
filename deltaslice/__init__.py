"""deltaslice: a slicer-to-motion compiler for parallel-kinematics printers and engravers.

Pipeline (one module per stage, each returns a new object):

    part.stl --mesh--> Mesh --slicing--> Toolpath --planning--> Trajectory --emit--> file

The package imports nothing heavy until a name is used (``deltaslice.load_printer`` loads
numpy and the kinematics on first access), so the command line can install its Ctrl-C
handling before numpy, scipy or trimesh are imported.
"""

from .errors import (
    DeltasliceError,
    GcodeError,
    MeshError,
    OutputError,
    PlanningError,
    PrinterFileError,
    StreamError,
    ToolpathWarning,
    UnreachableError,
)

__version__ = "0.1.0"

_LAZY = {"Printer": "machine", "load_printer": "machine", "Role": "toolpath", "Toolpath": "toolpath"}


def __getattr__(name):
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'deltaslice' has no attribute {name!r}")


__all__ = [
    "DeltasliceError",
    "GcodeError",
    "MeshError",
    "OutputError",
    "PlanningError",
    "PrinterFileError",
    "StreamError",
    "ToolpathWarning",
    "UnreachableError",
    "Printer",
    "load_printer",
    "Role",
    "Toolpath",
    "__version__",
]
