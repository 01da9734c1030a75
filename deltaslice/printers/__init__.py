"""The printer files shipped with deltaslice (package data, so an installed wheel has them).

``deltaslice printers`` lists them and ``--printer NAME`` (or ``load_printer("NAME")``)
finds one by name; the repository's ``printers/`` folder is a link to this one.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path


def shipped_names() -> list[str]:
    """Names of the shipped printer files (without ``.toml``), sorted."""
    return sorted(p.name[:-5] for p in resources.files(__name__).iterdir() if p.name.endswith(".toml"))


def shipped_path(name: str) -> Path | None:
    """The shipped file ``NAME.toml`` as a path, or None when there is no such printer."""
    if name not in shipped_names():
        return None
    return Path(str(resources.files(__name__).joinpath(f"{name}.toml")))
