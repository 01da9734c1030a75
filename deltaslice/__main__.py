"""``python -m deltaslice``: the same as the ``deltaslice`` command."""

from . import interrupt

interrupt.install()  # before the heavy imports below: Ctrl-C during them must not be lost

from .cli import run  # noqa: E402

run()
