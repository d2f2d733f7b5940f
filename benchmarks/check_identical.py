"""Do two commits give the same results? Runs the command line of each on real data and compares
every output byte for byte.

For each commit (default: ``main`` against the working tree; ``--base REV --head REV`` for two
commits) this makes a git worktree of it under a temporary folder and runs that worktree's own
code (``python -m wiloc`` with ``PYTHONPATH=<worktree>``, this interpreter, so both share one
environment) with an empty cache (``--cache``, as ``WILOC_CACHE``) of its own:

- ``wiloc vocabulary`` on a training traversal, when the ``bow`` descriptor is asked for;
- ``wiloc localize --json`` for every method x descriptor x dataset (``fabmap`` reads FAB-MAP's
  evidence, so it runs with ``bow`` only; ``trained`` learns from a training pair);
- ``wiloc evaluate`` and ``wiloc compare`` of each dataset's results files, as tables and ``--json``.

Datasets (``$WILOC_DATA``, else ``../shared/data`` beside the repository): Gardens Point Walking
(``gp``: map day_right, query day_left; vocabulary and training pair night_right against
day_right) and Nordland (``nordland``: map summer, query winter, the first ``--frames`` frames of
each; the next ``--frames`` of each for the vocabulary (winter) and the training pair; folders of
symbolic links).

Both commits run in the same folder (``<tmp>/run``, moved aside once a commit is done), so paths
in outputs match. Compared: each command's exit code, stdout and stderr; every results file; the
cache's files by name, and each HDF5 file's datasets (bytes, dtype, shape) and attributes. Left
out, because they differ between any two runs of one commit: the clock (``seconds`` values of
--json, the cache's ``created``/``updated`` and a vocabulary's ``created``/``build_seconds``)
and the compiled kernels (``numba*`` folders). Prints a table of what was compared and what
differs, and each command that failed (exit code not 0, on either commit) with its last error
line; exits 1 on any difference or failed command (a check of commands that all failed alike
proves nothing), 0 when every command ran and every output is identical. A bad option or a
dataset folder missing ends it with one error line before any commit is run.

    .venv/bin/python benchmarks/check_identical.py                        # main vs working tree, all
    .venv/bin/python benchmarks/check_identical.py --methods fabmap --datasets gp
    .venv/bin/python benchmarks/check_identical.py --base main~1 --head main --descriptors sad,gist

A quick check (``--methods online --descriptors sad --datasets gp``) took 42 s on a 2-core machine;
every method and descriptor on Gardens Point 9 to 12 minutes, on 300 Nordland frames 4.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np
from rich.markup import escape
from rich.table import Table

from bench_common import at_least, default_data_root, folder_problem, last_error_line, plain_console

REPO = Path(__file__).resolve().parents[1]
DESCRIPTORS = ("sad", "gist", "brisk-gist", "bow")
DATASETS = ("gp", "nordland")
#: Methods that read FAB-MAP's evidence rows, which only the ``bow`` descriptor gives.
BOW_ONLY = frozenset({"fabmap"})
#: Attributes of cache files that hold the clock.
CLOCK_ATTRIBUTES = frozenset({"created", "updated", "build_seconds"})
#: --json keys that hold the clock.
CLOCK_KEYS = frozenset({"seconds", "build_seconds"})
#: Cache folders of compiled kernels, keyed by source paths and machine.
SKIPPED_FOLDER = re.compile(r"^numba")
#: Rich tables as wide on every machine.
ENVIRONMENT = {"COLUMNS": "200", "NO_COLOR": "1", "TERM": "dumb"}
console = plain_console(width=shutil.get_terminal_size((160, 24)).columns)


@dataclass(frozen=True)
class Dataset:
    """One test pair and the pair it learns from (the vocabulary: the training query)."""

    name: str
    query: Path
    reference: Path
    train_query: Path
    train_reference: Path


def source_folders(name: str, root: Path) -> list[Path]:
    """The folders under the data folder ``root`` that dataset ``name`` reads."""
    if name == "gp":
        return [root / "gardens-point-walking" / walk for walk in ("day_left", "day_right", "night_right")]
    return [root / "nordland-summer-winter-64x32" / season for season in ("summer", "winter")]


def check_options(parser: argparse.ArgumentParser, args: argparse.Namespace, root: Path) -> None:
    """The usage error (exit 2) for a bad option, or an error line (exit 1) for a dataset folder
    missing under ``root``: before any worktree is made or command run."""
    for option, rev in (("--base", args.base), ("--head", args.head)):
        if rev is not None and not is_commit(rev):
            parser.error(f"{option} {rev}: not a commit")
    at_least(parser, "--frames", args.frames)
    for option, noun, names, known in (("--descriptors", "descriptor", args.descriptors, DESCRIPTORS),
                                       ("--datasets", "dataset", args.datasets, DATASETS)):
        for name in names.split(","):
            if name not in known:
                parser.error(f"{option}: unknown {noun} {name!r} (choose from {', '.join(known)})")
    for folder in (folder for name in args.datasets.split(",") for folder in source_folders(name, root)):
        if folder_problem(folder):
            sys.exit(f"error: {folder}: {folder_problem(folder)}")


def is_commit(rev: str) -> bool:
    """Whether ``rev`` names a commit of the repository."""
    return subprocess.run(["git", "-C", str(REPO), "rev-parse", "--verify", "--quiet", f"{rev}^{{commit}}"],
                          capture_output=True, check=False).returncode == 0


def datasets(names: list[str], root: Path, scratch: Path, frames: int) -> list[Dataset]:
    """The datasets asked for; Nordland cut to ``frames`` frames as folders of links in ``scratch``
    (test pair: the first ``frames``, training: the next ``frames``)."""
    chosen = []
    for name in names:
        if name == "gp":
            gp = root / "gardens-point-walking"
            chosen.append(Dataset("gp", gp / "day_left", gp / "day_right", gp / "night_right", gp / "day_right"))
        elif name == "nordland":
            nordland = root / "nordland-summer-winter-64x32"
            cut = {}
            for season in ("summer", "winter"):
                images = sorted((nordland / season).iterdir(), key=lambda p: _natural(p.name))
                for part, chunk in (("", images[:frames]), ("_train", images[frames:2 * frames])):
                    folder = scratch / "nordland" / f"{season}{part}"
                    folder.mkdir(parents=True)
                    for image in chunk:
                        (folder / image.name).symlink_to(image)
                    cut[f"{season}{part}"] = folder
            chosen.append(Dataset("nordland", cut["winter"], cut["summer"], cut["winter_train"], cut["summer_train"]))
    return chosen


def _natural(name: str) -> list[Any]:
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", name)]


def worktree(rev: str, folder: Path) -> Path:
    """A detached git worktree of ``rev`` in ``folder``."""
    subprocess.run(["git", "-C", str(REPO), "worktree", "add", "--detach", "-q", str(folder), rev], check=True)
    return folder


class Runner:
    """Runs one commit's command line in ``work`` and keeps each command's exit code and output
    under ``work/logs``."""

    def __init__(self, code: Path, work: Path) -> None:
        self.code = code
        self.work = work
        self.cache = work / "cache"
        self.results = work / "results"
        self.logs = work / "logs"
        for folder in (self.results, self.logs):
            folder.mkdir(parents=True)
        self.count = 0

    def __call__(self, name: str, *args: str) -> subprocess.CompletedProcess[str]:
        env = {**os.environ, **ENVIRONMENT, "PYTHONPATH": str(self.code), "WILOC_CACHE": str(self.cache)}
        done = subprocess.run([sys.executable, "-m", "wiloc", *args], cwd=self.work, env=env,
                              capture_output=True, text=True, check=False)
        self.count += 1
        stem = self.logs / f"{self.count:03d}-{name}"
        Path(f"{stem}.args").write_text(" ".join(args) + "\n")
        Path(f"{stem}.rc").write_text(f"{done.returncode}\n")
        Path(f"{stem}.out").write_text(done.stdout)
        Path(f"{stem}.err").write_text(done.stderr)
        state = "ok" if done.returncode == 0 else f"exit {done.returncode}"
        console.print(f"  {name}: {state}", highlight=False)
        return done


def methods_of(code: Path) -> list[str]:
    """The method names registered at a commit."""
    text = subprocess.run([sys.executable, "-c", "from wiloc.methods.registry import METHODS; print(*METHODS)"],
                          env={**os.environ, "PYTHONPATH": str(code)}, capture_output=True, text=True, check=True)
    return text.stdout.split()


def run_commit(code: Path, work: Path, sets: list[Dataset], methods: list[str], descriptors: list[str]) -> None:
    """Every command of the check, with one commit's code, outputs in ``work``."""
    run = Runner(code, work)
    for data in sets:
        vocabulary = None
        if "bow" in descriptors:
            done = run(f"{data.name}-vocabulary", "vocabulary", str(data.train_query), "--words", "64",
                       "--iterations", "5", "--max-features", "200", "--json")
            if done.returncode == 0:
                vocabulary = json.loads(done.stdout)["results"][0]["file"]
        written = []
        for descriptor in descriptors:
            extra = ["--vocabulary", vocabulary] if descriptor == "bow" and vocabulary else []
            for method in methods:
                if method in BOW_ONLY and descriptor != "bow":
                    continue
                if method == "trained":
                    extra_method = ["--train-query", str(data.train_query), "--train-map", str(data.train_reference),
                                    "--train-gt", "aligned"]
                else:
                    extra_method = []
                out = run.results / f"{data.name}-{descriptor}-{method}.csv"
                done = run(f"{data.name}-{descriptor}-{method}", "localize", str(data.query), "--map",
                           str(data.reference), "--descriptor", descriptor, *extra, "--method", method,
                           *extra_method, "--out", str(out), "--json")
                if done.returncode == 0:
                    written.append(str(out))
        if written:
            for command in ("evaluate", "compare"):
                run(f"{data.name}-{command}", command, *written, "--gt", "aligned")
                run(f"{data.name}-{command}-json", command, *written, "--gt", "aligned", "--json")


def failed_commands(run: Path) -> list[str]:
    """Each command of a commit's run (its outputs in ``run``) that exited non-zero, with its exit
    code and the last line of its stderr (why it failed)."""
    failed = []
    for rc in sorted((run / "logs").glob("*.rc")):
        code = int(rc.read_text())
        if code:
            failed.append(f"{rc.stem} (exit {code}): {last_error_line(rc.with_suffix('.err').read_text(), code)}")
    return failed


def without_clock(value: Any) -> Any:
    """A --json document with the clock's values replaced by a mark."""
    if isinstance(value, dict):
        return {k: "<clock>" if k in CLOCK_KEYS else without_clock(v) for k, v in value.items()}
    if isinstance(value, list):
        return [without_clock(v) for v in value]
    return value


def printed(path: Path) -> bytes:
    """A command's stdout as compared: a --json document without the clock, else the bytes."""
    data = path.read_bytes()
    if path.with_suffix(".args").read_text().rstrip().endswith("--json"):
        try:
            return json.dumps(without_clock(json.loads(data)), indent=1).encode()
        except ValueError:
            return data
    return data


def h5_content(path: Path) -> Iterator[tuple[str, bytes]]:
    """An HDF5 file as (name, bytes) items: each attribute but the clock's, each dataset's dtype,
    shape and values."""
    def attrs(name: str, obj: Any) -> Iterator[tuple[str, bytes]]:
        for key in sorted(obj.attrs):
            if key not in CLOCK_ATTRIBUTES:
                yield f"{name}@{key}", repr(obj.attrs[key]).encode()

    with h5py.File(path, "r") as f:
        yield from attrs("/", f)
        names: list[str] = []
        f.visit(names.append)
        for name in sorted(names):
            obj = f[name]
            yield from attrs(name, obj)
            if isinstance(obj, h5py.Dataset):
                values = obj[()]
                raw = repr(values.tolist()).encode() if values.dtype == object else np.ascontiguousarray(values).tobytes()
                yield name, f"{obj.dtype} {obj.shape} ".encode() + raw


def cache_files(cache: Path) -> dict[str, Path]:
    """The cache's files by relative name, the compiled kernels left out."""
    if not cache.is_dir():
        return {}
    return {str(p.relative_to(cache)): p for p in sorted(cache.rglob("*"))
            if p.is_file() and not SKIPPED_FOLDER.match(p.relative_to(cache).parts[0])}


def first_difference(a: bytes, b: bytes) -> str:
    """Where two byte strings first differ, as a short readable note."""
    at = next((i for i, (x, y) in enumerate(zip(a, b)) if x != y), min(len(a), len(b)))
    line = a[:at].count(b"\n") + 1
    return f"line {line}: {a[at:at + 40]!r} vs {b[at:at + 40]!r}" if at < max(len(a), len(b)) else ""


def compare_file(a: Path | None, b: Path | None, content: Any = None) -> str:
    """'' when the two files match (``content`` maps a path to what is compared), else why not."""
    if a is None or b is None:
        return "only in base" if b is None else "only in head"
    if content is None:
        one, two = a.read_bytes(), b.read_bytes()
        return "" if one == two else first_difference(one, two)
    one, two = dict(content(a)), dict(content(b))
    differ = sorted(k for k in one.keys() | two.keys() if one.get(k) != two.get(k))
    return "" if not differ else "differ: " + ", ".join(differ[:4]) + (" ..." if len(differ) > 4 else "")


def compare(base: Path, head: Path) -> list[tuple[str, str, str]]:
    """(kind, name, '' or the difference) for every output of the two runs."""
    rows = []
    stems = sorted({p.stem for folder in (base, head) for p in (folder / "logs").iterdir()})
    for stem in stems:
        for kind, label in (("rc", "exit code"), ("out", "stdout"), ("err", "stderr")):
            a, b = base / "logs" / f"{stem}.{kind}", head / "logs" / f"{stem}.{kind}"
            rows.append((label, stem, compare_file(a if a.exists() else None, b if b.exists() else None,
                                                   (lambda p: [("", printed(p))]) if kind == "out" else None)))
    for name in sorted({p.name for run in (base, head) for p in (run / "results").iterdir()}):
        a, b = base / "results" / name, head / "results" / name
        rows.append(("results file", name, compare_file(a if a.exists() else None, b if b.exists() else None)))
    one, two = cache_files(base / "cache"), cache_files(head / "cache")
    for name in sorted(one.keys() | two.keys()):
        h5 = name.endswith(".h5")
        rows.append(("cache file", name, compare_file(one.get(name), two.get(name), h5_content if h5 else None)))
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--base", default="main", help="the commit to compare against (default: main)")
    parser.add_argument("--head", default=None, help="the commit to check (default: the working tree)")
    parser.add_argument("--methods", default=None, help="comma-separated (default: every registered method)")
    parser.add_argument("--descriptors", default=",".join(DESCRIPTORS), help="comma-separated (default: %(default)s)")
    parser.add_argument("--datasets", default=",".join(DATASETS), help="comma-separated (default: %(default)s)")
    parser.add_argument("--frames", type=int, default=300, help="Nordland frames per traversal (default: %(default)s)")
    parser.add_argument("--keep", action="store_true", help="keep the temporary folder and say where it is")
    args = parser.parse_args(argv)
    check_options(parser, args, default_data_root())
    scratch = Path(tempfile.mkdtemp(prefix="wiloc-identical-"))
    trees = []
    try:
        sets = datasets(args.datasets.split(","), default_data_root(), scratch / "data", args.frames)
        trees.append(worktree(args.base, scratch / "base-code"))
        if args.head is not None:
            trees.append(worktree(args.head, scratch / "head-code"))
        base_code, head_code = trees[0], trees[1] if args.head is not None else REPO
        methods = args.methods.split(",") if args.methods else methods_of(base_code)
        descriptors = args.descriptors.split(",")
        for label, code in (("base", base_code), ("head", head_code)):
            console.print(f"[bold]{label}[/bold]: {args.base if label == 'base' else args.head or 'working tree'}"
                          f" ({code})", highlight=False)
            run_commit(code, scratch / "run", sets, methods, descriptors)
            (scratch / "run").rename(scratch / label)
        rows = compare(scratch / "base", scratch / "head")
        failed = {label: failed_commands(scratch / label) for label in ("base", "head")}
    finally:
        for tree in trees:
            subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force", str(tree)], check=False)
        if not args.keep:
            shutil.rmtree(scratch, ignore_errors=True)
    view = Table(title=f"{args.base} vs {args.head or 'working tree'}")
    for column in ("kind", "output", "status"):
        view.add_column(column)
    for kind, name, difference in rows:
        view.add_row(kind, name, "[green]identical[/green]" if not difference else f"[red]{escape(difference)}[/red]")
    console.print(view)
    for label, lines in failed.items():
        for line in lines:
            console.print(f"failed on {label}: {escape(line)}", highlight=False, soft_wrap=True)
    differ = sum(1 for row in rows if row[2])
    failures = sum(map(len, failed.values()))
    console.print(f"{len(rows)} outputs compared, {differ} differ, {failures} commands failed"
                  + (f"; kept in {scratch}" if args.keep else ""), highlight=False)
    return 1 if differ or failures else 0


if __name__ == "__main__":
    sys.exit(main())
