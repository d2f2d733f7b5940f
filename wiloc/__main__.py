"""The `wiloc` command (and ``python -m wiloc``).

Ctrl-C ends any command as one line and exit code 130, never a traceback, never a hang and never
silently. Python raises it wherever the main thread happens to be, which is unsafe in one place:
inside the import system (numpy, OpenCV and numba load for the first second, and the work imports
more as it goes). There an interrupt can end between a module lock's acquire and its release, so
that the next import of that module, in any thread, waits forever; or inside the import system's
own callback, where Python drops it and the command runs on to exit code 0. The same holds for
numba's compiler (the kernels compile on their first call, for seconds when the cache is cold): an
interrupt there leaves the kernel half-built, and numba reports that as an error of its own that no
longer says it was Ctrl-C. The command's handler therefore holds Ctrl-C while the main thread
imports or compiles and delivers it again as soon as that is done. An interrupt that a library
swallows elsewhere (typer's pydantic, building its validators, reports it as "Exception ignored"
and goes on) is delivered again too. Once the command is done, Ctrl-C no longer kills the process
mid-exit: it ends with the command's own exit code. A command started with Ctrl-C ignored (in the
background by a non-interactive shell) keeps ignoring it, as Python itself does: the shell meant
Ctrl-C for the foreground job alone.

A reader of the output that stops reading (``wiloc localize --help | head -3``) ends the command
quietly with exit code 1, as rich, which prints the tables, ends it when the pipe closes inside one
of its prints: what was done stays done (the cache, a results file written whole), and nothing
more is printed.
"""
from __future__ import annotations

import _thread
import os
import signal
import sys
import threading
from types import FrameType
from typing import Any

# nothing of wiloc's own before main() has installed its Ctrl-C handler: the console script
# imports this module first

#: How long a Ctrl-C that arrived during an import or a compile waits before it is delivered
#: again (seconds).
RETRY_SECONDS = 0.02

#: The packages of numba's compiler, as they appear in a frame's file name.
_COMPILER = (f"{os.sep}numba{os.sep}", f"{os.sep}llvmlite{os.sep}")


def _uninterruptible(frame: FrameType | None) -> bool:
    """Whether the main thread, at ``frame``, is inside the import system or numba's compiler."""
    while frame is not None:
        name = frame.f_code.co_filename
        if name.startswith("<frozen importlib") or any(package in name for package in _COMPILER):
            return True
        frame = frame.f_back
    return False


def _deliver_later() -> None:
    """Deliver Ctrl-C to the main thread again in :data:`RETRY_SECONDS`."""
    timer = threading.Timer(RETRY_SECONDS, _thread.interrupt_main, (signal.SIGINT,))
    timer.daemon = True
    timer.start()


def _on_ctrl_c(signum: int, frame: FrameType | None) -> None:
    """The SIGINT handler: KeyboardInterrupt, held back while the main thread imports or
    compiles."""
    if _uninterruptible(frame):
        _deliver_later()
        return
    raise KeyboardInterrupt


def _deliver_swallowed_interrupt(unraisable: Any) -> None:
    """``sys.unraisablehook``: Ctrl-C swallowed where Python could not raise it is delivered
    again (from another thread: raised in this hook, it would be swallowed once more); anything
    else is reported as Python reports it."""
    from wiloc.errors import interrupted

    if interrupted(unraisable.exc_value):
        _deliver_later()
    else:
        sys.__unraisablehook__(unraisable)


def _hold_standard_descriptors() -> None:
    """Descriptors 0-2 that the command was started without (`2>&-`) are opened on /dev/null:
    else the next file opened (a cache file, an image) would take the number, and what libraries
    print to stderr themselves (libjpeg's warnings) would be written into it."""
    for fd in (0, 1, 2):
        try:
            os.fstat(fd)
        except OSError:
            os.open(os.devnull, os.O_RDWR)  # the lowest free descriptor: this one


def _printable_everywhere() -> None:
    """A character that stdout or stderr cannot encode (PYTHONIOENCODING=ascii, a help text's
    "…", a folder named zürich) is printed as its escape (``\\xfc``), as file names that are not
    UTF-8 are, rather than ending the command in a UnicodeEncodeError."""
    for stream in (sys.stdout, sys.stderr):
        if stream is not None and hasattr(stream, "reconfigure"):
            stream.reconfigure(errors="backslashreplace")


class _NamedOutput:
    """sys.stdout, whose write errors name it: an OSError without a file name would be printed as
    ``[Errno 28] No space left on device`` (``wiloc ... > /dev/full``), naming no place."""

    NAME = "standard output"

    def __init__(self, stream: Any) -> None:
        self._stream = stream

    def _named(self, exc: OSError) -> OSError:
        return type(exc)(exc.errno, exc.strerror, self.NAME)

    def write(self, text: str) -> int:
        try:
            return self._stream.write(text)
        except OSError as exc:
            raise self._named(exc) from None

    def flush(self) -> None:
        try:
            self._stream.flush()
        except OSError as exc:
            raise self._named(exc) from None

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)


def _discard_output() -> None:
    """Standard output on /dev/null: what is still buffered for it, which can no longer be
    written, goes nowhere at exit instead of failing again there."""
    os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())


def main() -> int:
    """Run the command line; its exit code."""
    _hold_standard_descriptors()
    _printable_everywhere()
    if sys.stdout is not None:
        sys.stdout = _NamedOutput(sys.stdout)
    if signal.getsignal(signal.SIGINT) != signal.SIG_IGN:
        signal.signal(signal.SIGINT, _on_ctrl_c)  # first: everything after it may import
    sys.unraisablehook = _deliver_swallowed_interrupt
    from wiloc.errors import EXIT_BAD_INPUT, EXIT_CLOSED_OUTPUT, EXIT_INTERRUPTED, interrupted
    from wiloc.quiet import stderr_back

    try:
        from wiloc.cli import run
        code = run()
        if sys.stdout is not None:  # None: started with stdout closed (`>&-`)
            sys.stdout.flush()  # here, not at exit, where a closed reader would be a traceback
    except BrokenPipeError:  # the output's reader has gone
        _discard_output()
        code = EXIT_CLOSED_OUTPUT
    except OSError as exc:
        if exc.filename != _NamedOutput.NAME:
            raise
        stderr_back()
        sys.stderr.write(f"error: {exc.filename}: {exc.strerror}\n")  # its buffered end (a full disk)
        _discard_output()
        code = EXIT_BAD_INPUT
    except BaseException as exc:
        if not interrupted(exc):
            raise
        stderr_back()  # a Ctrl-C may end image decoders' quiet stretch before it puts stderr back
        sys.stderr.write("error: interrupted\n")
        code = EXIT_INTERRUPTED
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    return code


if __name__ == "__main__":
    sys.exit(main())
