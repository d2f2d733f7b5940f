"""What the benchmarks that run methods on re-sampled real traversals share (``bench_pace``,
``bench_loops``): where the data is, ``--param method.key=value`` options, the ``--odometry``
noise, and printing; and the
console every benchmark prints with, the line a failed child process is reported by, and the checks
that end a benchmark given a bad option or missing data with one error line before any work."""
from __future__ import annotations

import argparse
import json
import math
import os
from collections.abc import Collection, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from rich.console import Console

from wiloc.atomic import written_whole
from wiloc.errors import WilocError

REPO = Path(__file__).resolve().parents[1]
ODOMETRY_SEED = 0  # the draw of --odometry's noise: every method and run gets the same steps


def default_data_root() -> Path:
    """$WILOC_DATA, else the shared data folder beside the repository."""
    return Path(os.environ.get("WILOC_DATA") or REPO.parent / "shared" / "data")


def parser(doc: str, methods: str, example: str) -> argparse.ArgumentParser:
    """The options every such benchmark takes: the data folder, ``--methods`` (default
    ``methods``), ``--param`` (``example``: one for the help) and ``--json``; the script adds its own."""
    made = argparse.ArgumentParser(description=doc.split("\n\n")[0],
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
    made.add_argument("data", nargs="?", type=Path, default=default_data_root(),
                      help="folder holding the datasets (default: $WILOC_DATA or ../shared/data)")
    made.add_argument("--methods", default=methods, help="comma-separated (default: %(default)s)")
    made.add_argument("--param", action="append", default=[], metavar="METHOD.KEY=VALUE",
                      help=f"a method parameter, repeatable (e.g. {example})")
    made.add_argument("--json", type=Path, default=None, help="write every row to this file")
    return made


def add_odometry(parser: argparse.ArgumentParser, what: str) -> None:
    """``--odometry SD``: give methods that take odometry ``what``, each step noisy (:func:`noisy_steps`)."""
    parser.add_argument("--odometry", type=float, default=None, metavar="SD",
                        help=f"give methods that take odometry {what}, each step times 1 + SD x N(0, 1) (0: exact; "
                             "default: no odometry)")


def odometry_problem(noise: float | None) -> str | None:
    """Why ``--odometry``'s value is refused, or None."""
    if noise is not None and not (math.isfinite(noise) and noise >= 0):
        return f"--odometry {noise:g}: give a noise of 0 (exact) or more"
    return None


def odometry_for(method: str, noise: float | None) -> float | None:
    """The noise of the odometry ``method`` is given: ``noise`` when it takes odometry, else None
    (it runs without)."""
    from wiloc.methods.registry import METHODS

    return noise if noise is not None and "odometry" in METHODS[method].needs else None


def noisy_steps(steps: NDArray[np.float64], noise: float, seed: int = ODOMETRY_SEED) -> NDArray[np.float64]:
    """Travelled distances per frame as an odometry measures them: each times 1 + ``noise`` x
    N(0, 1), clipped at 0, drawn with ``seed`` (every method and run gets the same steps)."""
    steps = np.asarray(steps, dtype=np.float64).copy()
    if noise > 0:
        steps *= np.maximum(0.0, 1.0 + noise * np.random.default_rng(seed).standard_normal(steps.size))
    return steps


def parse_value(text: str) -> Any:
    """A parameter value typed on the command line: none, true/false, an int, a float, or
    comma-separated numbers (a tuple); anything else stays text."""
    lowered = text.strip().lower()
    if lowered in ("none", "null"):
        return None
    if lowered in ("true", "false"):
        return lowered == "true"
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    if "," in text:
        try:
            return tuple(float(part) for part in text.split(",") if part.strip())
        except ValueError:
            pass
    return text


def parse_params(items: Sequence[str], methods: Sequence[str]) -> dict[str, dict[str, Any]]:
    """``method.key=value`` items as {method: {key: value}}, one entry per method run; an item for
    a method not run is refused."""
    params: dict[str, dict[str, Any]] = {m: {} for m in methods}
    for item in items:
        target, sep, value = item.partition("=")
        method, dot, key = target.partition(".")
        if not sep or not dot or not key:
            raise SystemExit(f"--param {item!r}: give method.key=value (e.g. catgraph.particles=4000)")
        if method not in params:
            raise SystemExit(f"--param {item!r}: method {method!r} is not run")
        params[method][key] = parse_value(value)
    return params


def last_error_line(stderr: str, code: int) -> str:
    """What a failed child process said last on ``stderr`` (its error line, or the end of its
    traceback), else its exit status ``code``: the one line that says why it failed."""
    said = stderr.strip().splitlines()
    return said[-1] if said else f"exit status {code}"


def at_least(parser: argparse.ArgumentParser, option: str, value: int, least: int = 1) -> int:
    """``value`` of ``option``, or the usage error (exit 2) saying it must be at least ``least``."""
    if value < least:
        parser.error(f"{option} must be at least {least}, got {value}")
    return value


def whole_numbers(parser: argparse.ArgumentParser, option: str, text: str, least: int = 1) -> list[int]:
    """``option``'s comma-separated whole numbers, each at least ``least``, or the usage error (exit 2)."""
    try:
        numbers = [int(part) for part in text.split(",")]
    except ValueError:
        parser.error(f"{option} must be whole numbers, comma-separated, got {text!r}")
    for number in numbers:
        at_least(parser, option, number, least)
    return numbers


def known_methods(parser: argparse.ArgumentParser, option: str, text: str, known: Collection[str]) -> list[str]:
    """``option``'s comma-separated method names, each one of ``known``, or the usage error (exit 2)
    naming the first that is not: a typo runs nothing rather than being skipped."""
    names = [name.strip() for name in text.split(",") if name.strip()]
    for name in names:
        if name not in known:
            parser.error(f"{option}: unknown method {name!r} (choose from {', '.join(known)})")
    return names


def folder_problem(folder: Path) -> str | None:
    """Why ``folder`` cannot be written into ("folder does not exist", "not a folder"), or None."""
    if folder.is_dir():
        return None
    return "not a folder" if folder.exists() else "folder does not exist"


def check_json_target(parser: argparse.ArgumentParser, path: Path | None) -> None:
    """``--json PATH``: the usage error (exit 2) before any work when the file cannot be written
    there (its folder missing or a file, or PATH a folder), rather than a traceback after the run."""
    if path is None:
        return
    folder = path.parent
    if path.is_dir():
        parser.error(f"--json {path}: is a folder")
    if not folder.exists():
        parser.error(f"--json {path}: folder {folder} does not exist")
    if not folder.is_dir():
        parser.error(f"--json {path}: {folder} is not a folder")


@contextmanager
def data_errors(parser: argparse.ArgumentParser) -> Iterator[None]:
    """A ``WilocError`` raised inside (the data: a folder missing or unreadable) as one line
    ``error: ...`` and its exit code, as wiloc's own commands end, never a traceback."""
    try:
        yield
    except WilocError as exc:
        parser.exit(exc.exit_code, f"error: {exc}\n")


def plain_console(**options: Any) -> Console:
    """A rich console (``options`` as ``Console`` takes them) that prints text as given, as wiloc's
    own do: emoji codes off, so that a path holding ':name:' (a:smile:b) is not shown as an emoji."""
    return Console(emoji=False, **options)


def wide_console(width: int = 220) -> Console:
    """The console a table is printed with: the terminal's width, or ``width`` for a file or a
    pipe (where rich would cut every table to 80 columns, its labels mid-word)."""
    console = plain_console()
    return console if console.is_terminal else plain_console(width=width)


def fmt(value: float | None, digits: int = 3) -> str:
    """A measure as printed: ``digits`` decimals, "-" for none or NaN."""
    return "-" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.{digits}f}"


def json_ready(value: Any) -> Any:
    """``value`` with numpy scalars as Python numbers and non-finite floats as None, for --json."""
    if isinstance(value, dict):
        return {k: json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_ready(v) for v in value]
    if hasattr(value, "item"):
        value = value.item()
    return None if isinstance(value, float) and not math.isfinite(value) else value


def write_json(path: Path | None, rows: list[dict[str, Any]], console: Any) -> None:
    """``--json``: every row to ``path`` (when given), and a line saying so; written whole or not
    at all (wiloc's ``written_whole``), so that a run killed meanwhile never leaves a truncated
    file that looks complete."""
    if path is None:
        return
    with written_whole(path, "the --json file") as out:
        out.write(json.dumps(json_ready(rows), indent=2) + "\n")
    console.print(f"wrote {path}")