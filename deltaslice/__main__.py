"""``python -m deltaslice``: the same as the ``deltaslice`` command."""

from .cli import main

main()
