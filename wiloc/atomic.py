"""Files written whole or not at all: the new content goes to a temporary file beside the target,
renamed onto it once complete, so a killed writer leaves the old file or the whole new one, never
a part that looks complete. Results files, metrics tables and figures are written this way."""
from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from glob import escape as glob_escape
from pathlib import Path
from typing import IO, Any

from wiloc.errors import WilocError


#: Why an output path that exists but is no regular file (a device, a pipe, a folder) is refused.
NOT_A_FILE = "it is not a regular file (a device, a pipe or a folder), which writing would replace"


def write_error(path: Path, what: str, exc: OSError) -> WilocError:
    """The one line an OSError writing ``path`` (a full disk, a folder that refuses) becomes:
    ``PATH: cannot write WHAT (why)``; the OSError alone would not name the file."""
    return WilocError(path, f"cannot write {what} ({exc.strerror or exc})")


@contextmanager
def written_whole(path: Path, what: str, *, binary: bool = False, mode: int | None = None) -> Iterator[IO[Any]]:
    """A temporary file beside ``path`` (``.NAME.<pid>.*.tmp``), open for the block to write
    (text in UTF-8 with newlines as written, or ``binary``); renamed onto ``path`` when the block
    ends, removed when it raises. Temporary files that killed writers left beside ``path`` are
    removed first. The file gets ``mode``, else the usual new-file mode; ``what`` names the file
    in the error that an OSError (a full disk, a folder that refuses) becomes. Something other than
    a regular file at ``path`` (a device such as /dev/full, a pipe) is refused, not replaced."""
    if path.exists() and not path.is_file():
        raise WilocError(path, f"cannot write {what}: {NOT_A_FILE}")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        _remove_orphans(path)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.{os.getpid()}.", suffix=".tmp", dir=path.parent)
        os.chmod(tmp, mode if mode is not None else 0o666 & ~_umask())
    except OSError as exc:
        raise write_error(path, what, exc) from None
    try:
        with os.fdopen(fd, "wb") if binary else os.fdopen(fd, "w", encoding="utf-8", newline="") as file:
            yield file
        os.replace(tmp, path)
    except BaseException as exc:
        Path(tmp).unlink(missing_ok=True)
        if isinstance(exc, OSError):
            raise write_error(path, what, exc) from None
        raise


def _umask() -> int:
    current = os.umask(0)
    os.umask(current)
    return current


def _remove_orphans(path: Path) -> None:
    """Delete ``.NAME.<pid>.*.tmp`` files beside ``path`` whose writing process is gone."""
    for temp in path.parent.glob(f".{glob_escape(path.name)}.*.tmp"):
        pid = temp.name[len(path.name) + 2:].split(".", 1)[0]
        if pid.isdigit() and not process_alive(int(pid)):
            temp.unlink(missing_ok=True)


def process_alive(pid: int) -> bool:
    """Whether process ``pid`` runs (a temporary file's writer, by the pid in its name)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, owned by another user
        pass
    return True
