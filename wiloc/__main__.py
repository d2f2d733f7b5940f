"""The `wiloc` command (and ``python -m wiloc``).

A small module on purpose: Ctrl-C while the command line is still loading (numpy, OpenCV: the
first second) ends as any interrupt does, one line and exit code 130, not a traceback from
inside an import. An interrupt that a library swallows (typer's pydantic, building its
validators, reports it as "Exception ignored" and goes on) is raised again as the command
starts. Once the command is done, Ctrl-C no longer kills the process mid-exit: it ends with the
command's own exit code.
"""
from __future__ import annotations

import signal
import sys
from typing import Any

from wiloc.errors import EXIT_INTERRUPTED, SWALLOWED_INTERRUPTS, interrupted


def _keep_swallowed_interrupt(unraisable: Any) -> None:
    """``sys.unraisablehook``: Ctrl-C that was swallowed where Python could not raise it is kept,
    silently, for the command to raise before its work starts; anything else is reported as
    Python reports it."""
    if interrupted(unraisable.exc_value):
        SWALLOWED_INTERRUPTS.append(unraisable.exc_value)
    else:
        sys.__unraisablehook__(unraisable)


def main() -> int:
    """Run the command line; its exit code."""
    sys.unraisablehook = _keep_swallowed_interrupt
    try:
        from wiloc.cli import run
        code = run()
    except BaseException as exc:
        if not interrupted(exc):
            raise
        sys.stderr.write("error: interrupted\n")
        code = EXIT_INTERRUPTED
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    return code


if __name__ == "__main__":
    sys.exit(main())
