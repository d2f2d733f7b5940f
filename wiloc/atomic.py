"""Files written whole or not at all: the new content goes to a temporary file beside the target,
renamed onto it once complete, so a killed writer leaves the old file or the whole new one, never
a part that looks complete. Results files, metrics tables and figures are written this way."""
from __future__ import annotations

import hashlib
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

#: The longest file name most file systems take (bytes); a temporary name is kept within it.
NAME_MAX = 255


def name_problem(path: Path) -> str | None:
    """Why no file can be named ``path`` (a part longer than file systems take, a path longer than
    the system takes), or None; asking the system about such a name raises an OSError."""
    longest = max((len(os.fsencode(part)) for part in path.parts), default=0)
    if longest > NAME_MAX:
        return f"no file can have this name (a part of {longest} bytes; file systems take at most {NAME_MAX})"
    try:
        path.exists()
    except OSError as exc:
        return f"no file can have this name ({exc.strerror or exc})"
    return None


def output_problem(path: Path) -> str | None:
    """Why ``path`` cannot take an output file, or None: a name no file can have
    (:func:`name_problem`), something there that is no regular file (it would be replaced), or
    the file this process prints to (``--csv /dev/stdout`` with the output redirected to a file:
    replacing it would lose what is printed)."""
    if (problem := name_problem(path)) is not None:
        return problem
    if path.exists() and not path.is_file():
        return NOT_A_FILE
    for fd, stream in ((1, "standard output"), (2, "standard error")):
        try:
            if os.path.samestat(os.fstat(fd), path.stat()):
                return f"it is this command's {stream}, which writing would replace (give a file of its own)"
        except OSError:  # no such stream, or no such file
            continue
    return None


def through_links(path: Path) -> Path:
    """Where writing ``path`` lands: a symbolic link is written through (its target gets the new
    file and the link stays, as a shell's ``>`` does), anything else is ``path`` itself."""
    return Path(os.path.realpath(path)) if path.is_symlink() else path


def cut_to_whole_lines(path: Path) -> None:
    """Cut a torn last line (a kill during its write) and an editor's blank lines (or lines of
    spaces) off the end of a text file that lines are appended to: lines appended after them
    would join the torn one or leave the blank ones between lines."""
    data = path.read_bytes()
    whole = data[:data.rfind(b"\n") + 1]  # the lines that end: a torn one has no newline yet
    kept = whole.find(b"\n", len(whole.rstrip())) + 1  # up to the newline of the last line not blank
    if kept < len(data):
        os.truncate(path, kept)


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
    in the error that an OSError (a full disk, a folder that refuses) becomes. What
    :func:`output_problem` names (a device such as /dev/full, a pipe, this process's own output)
    is refused, not replaced; a symbolic link is written through (:func:`through_links`)."""
    problem = output_problem(path)
    if problem is not None:
        raise WilocError(path, f"cannot write {what}: {problem}")
    target = through_links(path)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        _remove_orphans(target)
        fd, tmp = tempfile.mkstemp(prefix=f".{_temporary_stem(target.name)}.{os.getpid()}.", suffix=".tmp",
                                   dir=target.parent)
        os.chmod(tmp, mode if mode is not None else 0o666 & ~_umask())
    except OSError as exc:
        raise write_error(path, what, exc) from None
    try:
        with os.fdopen(fd, "wb") if binary else os.fdopen(fd, "w", encoding="utf-8", newline="") as file:
            yield file
        os.replace(tmp, target)
    except BaseException as exc:
        Path(tmp).unlink(missing_ok=True)
        if isinstance(exc, OSError):
            raise write_error(path, what, exc) from None
        raise


def _umask() -> int:
    current = os.umask(0)
    os.umask(current)
    return current


def _temporary_stem(name: str) -> str:
    """What stands for file ``name`` in its temporary files' names (a pid, a random part and a
    suffix are added, up to 24 bytes): :func:`fitting_stem`."""
    return fitting_stem(name, 24)


def fitting_stem(name: str, added: int) -> str:
    """What stands for file ``name`` in the name of a file kept beside it (a temporary file, a
    lock), ``added`` bytes longer: the name itself, or when that would pass :data:`NAME_MAX`
    bytes, its first bytes and a digest of the whole, so that a name the file system takes is
    never refused for its companion's sake."""
    raw = name.encode("utf-8", "surrogateescape")
    if len(raw) <= NAME_MAX - added:
        return name
    digest = hashlib.sha1(raw).hexdigest()[:12]
    return raw[:NAME_MAX - added - 13].decode("utf-8", "ignore") + "~" + digest


def _remove_orphans(path: Path) -> None:
    """Delete ``.NAME.<pid>.*.tmp`` files beside ``path`` whose writing process is gone."""
    stem = _temporary_stem(path.name)
    for temp in path.parent.glob(f".{glob_escape(stem)}.*.tmp"):
        pid = temp.name[len(stem) + 2:].split(".", 1)[0]
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
