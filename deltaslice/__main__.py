"""``python -m deltaslice``: the same as the ``deltaslice`` command."""

from . import interrupt

# before the imports below: a Ctrl-C while they run (click, the command definitions) exits at
# once with the one interrupt line and status 130, not a traceback from inside an import
interrupt.install(at_once=True)

try:
    from .cli import run
except KeyboardInterrupt:  # pragma: no cover - the handler above exits first
    interrupt.exit_now()

run()
