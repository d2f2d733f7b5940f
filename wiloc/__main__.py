"""The `wiloc` command (and ``python -m wiloc``).

A small module on purpose: Ctrl-C while the command line is still loading (numpy, OpenCV: the
first second) ends as any interrupt does, one line and exit code 130, not a traceback from
inside an import. Once the command is done, Ctrl-C no longer kills the process mid-exit: it ends
with the command's own exit code.
"""
from __future__ import annotations

import signal
import sys

from wiloc.errors import EXIT_INTERRUPTED, interrupted


def main() -> int:
    """Run the command line; its exit code."""
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
