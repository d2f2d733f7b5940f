"""The `wiloc` command group: every command registered in the order the help lists them, the
version option, and :func:`run`."""
from __future__ import annotations

import os

import typer

from wiloc.cli.compare import compare
from wiloc.cli.core import Command, CommandLine, out
from wiloc.cli.demo import demo
from wiloc.cli.describe import describe
from wiloc.cli.evaluate import evaluate
from wiloc.cli.localize import localize
from wiloc.cli.report import report
from wiloc.cli.vocabulary import vocabulary
from wiloc.version import __version__

# FFmpeg inside OpenCV reads its log level once, when cv2 is loaded: keep its lines about damaged
# videos ("[mpeg4 @ 0x...] header damaged") off the terminal, since wiloc reports them itself.
os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")  # AV_LOG_QUIET

app = typer.Typer(
    name="wiloc", cls=CommandLine, add_completion=False, no_args_is_help=True, rich_markup_mode="rich",
    help="Appearance-based localization with whole-image descriptors and a probability model "
         "learned online.\n\nExample: [bold]wiloc demo[/bold], then\n\n"
         "  wiloc localize data/day_left --map data/day_right --descriptor sad --method online")
for command in (describe, vocabulary, localize, evaluate, compare, report, demo):
    app.command(cls=Command)(command)


def run(args: list[str] | None = None) -> int:
    """Run the command line on ``args`` (default: the process's) and return its exit code."""
    return typer.main.get_command(app).main(args, prog_name="wiloc", standalone_mode=False)


def _version(value: bool) -> None:
    if value:
        out.print(f"wiloc {__version__}")
        raise typer.Exit()


@app.callback()
def main(version: bool = typer.Option(False, "--version", callback=_version, is_eager=True,
                                      help="Print the version and exit.")) -> None:
    """wiloc: have I been here before, where, and how sure am I?"""
