"""The orchestrator: scenes, routes, results, reports and the ``uplift`` command line.

Run as the program (``uplift ...`` or ``python -m orchestrator.cli ...``), SIGINT is held from
here on while the modules load (``uplift_common.interrupts``): a Ctrl-C then ends the command
with exit 130 and one line, not with a traceback out of an import."""
from uplift_common import interrupts as _interrupts

if _interrupts.started_as("orchestrator.cli", "uplift"):
    _interrupts.install(held=True)
