"""The `wiloc` command (and ``python -m wiloc``).

A small module on purpose: Ctrl-C while the command line is still loading (numpy, OpenCV: the
first second) ends as any interrupt does, one line and exit code 130, not a traceback from
inside an import.
"""
from __future__ import annotations

import sys

from wiloc.errors import EXIT_INTERRUPTED


def main() -> int:
    """Run the command line; its exit code."""
    try:
        from wiloc.cli import run
        return run()
    except KeyboardInterrupt:
        sys.stderr.write("error: interrupted\n")
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
