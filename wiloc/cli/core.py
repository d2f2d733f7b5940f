"""What every `wiloc` command shares: the consoles, one-line errors with their exit codes, and
help pages that read well.

Every problem ends as one line on stderr, ``error: WHERE: PROBLEM``, and the documented exit code
(1 bad input, 2 usage, 3 cache busy, 130 interrupted), never a traceback or a boxed message:
library errors through :func:`handles_errors`, the parser's own (a missing argument, a value that
is no number, an unknown option or command) through :class:`CommandLine`, which runs the parser
with the same formatting from the console script and from a test runner. Help pages show
argument names in the usage line (``QUERY...``), no type placeholder for flags or arguments, and
every option's default.
"""
from __future__ import annotations

import functools
import re
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, NoReturn, get_args

import typer
from rich.console import Console
from rich.markup import escape
from typer import _click as click
from typer._click import exceptions as problems
from typer._click.core import ParameterSource
from typer._click.globals import get_current_context
from typer.core import TyperArgument, TyperCommand, TyperGroup, TyperOption

from wiloc.cli.params import flag, given
from wiloc.errors import EXIT_BAD_INPUT, EXIT_INTERRUPTED, EXIT_USAGE, UsageError, WilocError, interrupted
from wiloc.jitcache import numba_cache_failure
from wiloc.quiet import stderr_back

# emoji off: a path or value holding ':name:' (x:thumbs_up:y, the slice 1:100:2) is printed as typed
out = Console(emoji=False)
err = Console(stderr=True, emoji=False)
EMPTY_PATH = "an empty path; give a file or folder"  # a path option typed '' (an unset shell variable)


def error(message: str) -> None:
    """One unwrapped `error:` line on stderr (put back first if image decoders held it quiet)."""
    stderr_back()
    err.print(f"[bold red]error:[/bold red] {escape(message)}", highlight=False, soft_wrap=True)


def fail(message: str, code: int) -> NoReturn:
    """One `error:` line, then exit with ``code``."""
    error(message)
    raise typer.Exit(code)


def print_line(text: str) -> None:
    """One line on stdout, printed as it is (no markup, no highlighting), folded only at the
    console's width: a line naming a path stays whole where it fits, where a table's caption
    would fold it at the table's width."""
    out.print(escape(text), highlight=False)


def absolute_frame(path: str | Path) -> str:
    """A frame's path as --json gives it (docs/formats.md: paths are absolute): its folder (or
    video, or bag) resolved, its own name kept (a link to an image is named as the folder lists it)."""
    path = Path(path)
    return str(path.parent.resolve() / path.name)


def note(kind: str, message: str) -> None:
    """One unwrapped line on stderr about something left out or worth knowing."""
    err.print(f"[yellow]{kind}[/yellow] {escape(message)}", highlight=False, soft_wrap=True)


class Notes(list[str]):
    """The lines a command prints on stderr besides errors (frames left out, a file replaced):
    each printed as it is added, and kept for the ``warnings`` of the command's --json."""

    def add(self, kind: str, message: str) -> None:
        note(kind, message)
        self.append(f"{kind}: {message}")


def refuse_unused(uses: dict[str, tuple[bool, str]]) -> None:
    """A usage error for the first option typed on the command line that the chosen input does not
    use. ``uses`` maps the option's parameter name to (whether it is used, what it applies to)."""
    ctx = get_current_context()
    for name, (used, scope) in uses.items():
        if not used and given(name):
            param = next(p for p in ctx.command.params if p.name == name)
            raise UsageError(_name(param), f"applies to {scope} only")


def refuse_besides(option: str, takes: tuple[str, ...]) -> None:
    """A usage error for the first parameter typed on the command line besides ``option`` and
    those it ``takes`` (Python names), when ``option`` does one thing of its own (``--list``):
    the others would be ignored. Environment variables (``WILOC_SCHEDULER``) are not typed."""
    ctx = get_current_context()
    params = {p.name: p for p in ctx.command.params}
    for name, param in params.items():
        if name not in (option, *takes) and ctx.get_parameter_source(name) == ParameterSource.COMMANDLINE:
            alone = _name(params[option])
            raise UsageError(_name(param), f"does not go with {alone}, which takes "
                                           f"{' and '.join(_name(params[t]) for t in takes) or 'no other option'} only")


def handles_errors(func: Callable[..., Any]) -> Callable[..., Any]:
    """One line and an exit code for input problems, a failure of numba's kernel cache and Ctrl-C;
    never a traceback."""
    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except WilocError as exc:
            fail(f"{flag(exc.parameter)}: {exc.problem}" if exc.parameter else str(exc), exc.exit_code)
        except BrokenPipeError:
            raise  # the output's reader has gone (`| head`): the command ends quietly (wiloc.__main__)
        except BaseException as exc:
            numba_cache = None if interrupted(exc) else numba_cache_failure(exc)
            if numba_cache is not None:  # a damaged file of numba's, or a full disk naming no file
                fail(str(numba_cache), numba_cache.exit_code)
            if isinstance(exc, OSError):
                fail(f"{exc.filename}: {exc.strerror}" if exc.filename else str(exc), EXIT_BAD_INPUT)
            if not interrupted(exc):
                raise
            fail("interrupted; finished work is kept in the cache, rerun to resume", EXIT_INTERRUPTED)
    return wrapper


def _name(param: click.Parameter) -> str:
    """How the user spells a parameter: its long flag, or an argument's name (``QUERY...``)."""
    if isinstance(param, TyperArgument):
        return param.metavar or param.name.upper()
    return next((o for o in param.opts if o.startswith("--")), param.opts[0])


def _lower(text: str) -> str:
    text = text.strip().rstrip(".")
    return text[:1].lower() + text[1:]


#: The parser's wording of an option's misuse, as wiloc words it.
_PHRASES = {"requires an argument": "needs a value", "does not take a value": "takes no value"}


def _given(exc: problems.BadParameter) -> str:
    """", got 'abc'" when the parser's conversion says what value it could not convert."""
    errors = getattr(exc.__cause__, "errors", None)
    value = errors()[0].get("input") if callable(errors) and errors() else None
    return f", got {value!r}" if isinstance(value, str) else ""


def usage_problem(exc: problems.UsageError) -> str:
    """A parser error as ``WHERE: PROBLEM``."""
    ctx = exc.ctx
    command = ctx.command_path if ctx is not None else "wiloc"
    if isinstance(exc, problems.MissingParameter) and exc.param is not None:
        usage = ctx.get_usage().removeprefix("Usage: ") if ctx is not None else command
        return f"{_name(exc.param)}: missing (usage: {usage})"
    if isinstance(exc, problems.BadParameter) and exc.param is not None:  # a hint: the variable it came from
        return f"{exc.param_hint or _name(exc.param)}: {_lower(exc.message)}{_given(exc)}"
    if isinstance(exc, problems.NoSuchOption):
        close = sorted(exc.possibilities or [])
        hint = f"did you mean {' or '.join(close)}?" if close else f"{command} --help lists them"
        return f"{exc.option_name}: no such option of {command} ({hint})"
    if isinstance(exc, problems.BadOptionUsage):
        problem = re.sub(r"^Option .*? (?=requires|does)", "", exc.message).rstrip(".")
        return f"{exc.option_name}: {_PHRASES.get(problem, _lower(problem))}"
    unknown = re.match(r"No such command '(.*)'", exc.message)
    if unknown and ctx is not None and isinstance(ctx.command, TyperGroup):
        return f"{unknown.group(1)}: no such command ({', '.join(ctx.command.list_commands(ctx))})"
    return f"{command}: {_lower(exc.message)}"


def _plain_flag(param: click.Parameter) -> None:
    """A flag takes no value: show no ``<bool>`` type beside it."""
    if isinstance(param, TyperOption) and param.is_flag:
        param.metavar = ""


def _plain_help(param: click.Parameter) -> None:
    """How a parameter reads in help: a flag without ``<bool>``, an argument by its name alone
    (``FOLDER...``, not ``<list[Path]>`` beside it), an option without a default value saying
    ``[default: (none)]`` unless it names what happens then."""
    _plain_flag(param)
    if isinstance(param, TyperArgument):
        param.display_type_rich = lambda ctx: None  # type: ignore[method-assign]
    elif isinstance(param, TyperOption) and not param.is_flag and param.default is None \
            and not isinstance(param.show_default, str):
        param.show_default = "none"


def _no_empty_paths(param: click.Parameter) -> None:
    """A path parameter (``Path``, ``Optional[Path]``, ``list[Path]``) typed empty is a usage error
    naming it: ``-o "$OUT"`` with OUT unset would be ``Path("")``, the current folder, which a
    command described as a query, wrote its outputs into or made its cache in."""
    annotation = getattr(getattr(param, "type_descriptor", None), "annotation", None)
    if Path not in (annotation, *get_args(annotation)):
        return
    convert = param.process_value

    def refusing_empty(ctx: click.Context, value: Any) -> Any:
        if value == "" or (isinstance(value, (list, tuple)) and "" in value):
            raise problems.BadParameter(EMPTY_PATH, ctx=ctx, param=param)
        return convert(ctx, value)

    param.process_value = refusing_empty  # type: ignore[method-assign]


class _PlainFlags:
    """Help that shows no type placeholder beside a flag (including --help) or an argument, and
    every option's default; no path parameter may be typed empty."""

    params: list[click.Parameter]

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        for param in self.params:
            _plain_help(param)
            _no_empty_paths(param)

    def get_help_option(self, ctx: click.Context) -> TyperOption | None:
        option = super().get_help_option(ctx)  # type: ignore[misc]
        if option is not None:
            _plain_flag(option)
        return option


class Command(_PlainFlags, TyperCommand):
    """A command whose usage line names its arguments (``QUERY...``, ``[FOLDER]...``)."""

    def collect_usage_pieces(self, ctx: click.Context) -> list[str]:
        pieces = [self.options_metavar]
        for param in self.get_params(ctx):
            if isinstance(param, TyperArgument):
                pieces.append(_name(param) if param.required else f"[{_name(param)}]")
        return pieces


class CommandLine(_PlainFlags, TyperGroup):
    """The `wiloc` group: runs the parser and the command, and ends every problem as one line
    and its exit code, whether called from the console script (``standalone_mode=False``: the
    code is returned) or a test runner (the code goes to ``sys.exit``)."""

    def main(self, args: list[str] | None = None, prog_name: str | None = None, complete_var: str | None = None,
             standalone_mode: bool = True, **extra: Any) -> int:
        code = self._run(list(sys.argv[1:] if args is None else args), prog_name or "wiloc", extra)
        if standalone_mode:
            sys.exit(code)
        return code

    def _run(self, args: list[str], prog_name: str, extra: dict[str, Any]) -> int:
        try:
            with self.make_context(prog_name, args, **extra) as ctx:
                self.invoke(ctx)
        except problems.NoArgsIsHelpError:
            return EXIT_USAGE  # the help page is printed as the error is made
        except typer.Exit as exc:
            return exc.exit_code
        except problems.UsageError as exc:
            error(usage_problem(exc))
            return EXIT_USAGE
        except click.ClickException as exc:
            error(_lower(exc.format_message()))
            return exc.exit_code
        except typer.Abort:
            error("interrupted")
            return EXIT_INTERRUPTED
        except BaseException as exc:
            if not interrupted(exc):
                raise
            error("interrupted")
            return EXIT_INTERRUPTED
        return 0
