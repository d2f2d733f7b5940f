"""Command-line options made from the declared parameters of methods and descriptors, and flags
for library names.

Every parameter of every registered method becomes one ``--flag`` of ``wiloc localize``, shown in
the help panel of the method(s) that take it, with its default and valid range. A flag given for a
method that does not take it is a usage error naming the method. Every parameter of every
registered descriptor becomes one ``--flag`` of ``wiloc describe`` and ``wiloc localize`` the
same way, except those the command line takes in a form of its own (:data:`OWN_FORMS`). Library
errors name parameters (``particles``, ``map_odometry``); :func:`flag` turns those into the flags
a user typed. :func:`given` tells an option typed on the command line from its default.
"""
from __future__ import annotations

import functools
import inspect
from fractions import Fraction
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Optional

import typer
from typer._click.core import ParameterSource
from typer._click.globals import get_current_context

from wiloc.bow.vocabulary_params import VocabularyParams
from wiloc.descriptors.learned import KEYS as PREPROCESSING
from wiloc.descriptors.registry import DESCRIPTORS
from wiloc.errors import UsageError
from wiloc.methods.registry import METHODS
from wiloc.parameters import Declared, declared

#: Library parameter names whose flag is not simply ``--`` + the name with dashes.
FLAGS = {"reference": "--map", "training": "--train-query", "query_names_file": "--names",
         "ref_names_file": "--map-names",
         "path": "--gt", "ref_path": "--gt-map", "train_path": "--train-gt", "train_ref_path": "--train-gt-map",
         "precisions": "--precision", "runs": "RESULTS..."}

#: Descriptor parameters the command line takes in a form of its own, not a flag each: a vocabulary
#: ``file`` as ``--vocabulary`` (a file, or a key in the cache), a network's ``model`` as ``--model``
#: and its preprocessing as ``--preprocess KEY=VALUE``.
OWN_FORMS = {"file": "vocabulary", "model": "model", **{key: "preprocess" for key in PREPROCESSING}}

_TYPES = {"int": int, "float": float, "str": str, "bool": bool, "floats": str}


def flag(parameter: str) -> str:
    """The command-line flag of a library parameter name."""
    return FLAGS.get(parameter, "--" + parameter.replace("_", "-"))


def given(parameter: str) -> bool:
    """Whether the running command's option ``parameter`` (its Python name) was typed on the
    command line or set by its environment variable, rather than left at its default."""
    source = get_current_context().get_parameter_source(parameter)
    return source in (ParameterSource.COMMANDLINE, ParameterSource.ENVIRONMENT)


@dataclass(frozen=True)
class DeclaredOption:
    """One command-line option: a parameter name and the methods (or descriptors) that declare it."""

    name: str
    by_owner: dict[str, Declared]

    @property
    def first(self) -> Declared:
        return next(iter(self.by_owner.values()))

    @property
    def shared(self) -> bool:
        """Whether every method taking the option has the same default."""
        return len({d.default for d in self.by_owner.values()}) == 1

    def default(self) -> Any:
        """The option's default as it takes it (a list of numbers as text, each written so that
        typing the text shown gives the default itself: 1/3 as 1/3, not 0.333333); None when the
        methods taking it differ (the help then names each method's)."""
        value = self.first.default if self.shared else None
        return ",".join(map(_number_text, value)) if isinstance(value, tuple) else value

    def default_text(self) -> str | bool:
        """What the help shows as the default: the default itself, what happens without one when
        the parameter's help says so (``default: the share of ...``), or each method's when they
        differ."""
        if self.shared:
            return _said_default(self.first.help)[1] or True
        return "; ".join(f"{m}: {'none' if d.default is None else d.default}" for m, d in self.by_owner.items())

    def help(self) -> str:
        """The parameter's help, or each owner's (``online: ... fabmap: ...``) when they differ."""
        d = self.first
        texts = {m: _said_default(t.help)[0] if self.shared else t.help for m, t in self.by_owner.items()}
        same = len(set(texts.values())) == 1
        parts = [texts[next(iter(texts))] if same else " ".join(f"{m}: {text}" for m, text in texts.items())]
        if d.range_text:
            parts.append(f"({d.range_text})")
        if d.kind == "floats":
            parts.append("Comma-separated numbers (fractions such as 1/3 too).")
        return " ".join(parts)

    def parse(self, value: Any) -> Any:
        """The option's value as the parameter takes it (comma-separated text -> tuple of floats)."""
        if self.first.kind != "floats":
            return value
        try:
            return tuple(_number(part) for part in str(value).split(",") if part.strip())
        except (ValueError, ZeroDivisionError):
            raise UsageError(flag(self.name), f"give comma-separated numbers, got {value!r}") from None


def _number(text: str) -> float:
    """One number of a comma-separated list: a decimal, or a fraction such as 1/3 (exactly the
    float 1 / 3 is, which no decimal short enough to type is)."""
    top, slash, bottom = text.partition("/")
    return float(top) / float(bottom) if slash else float(text)


def _number_text(value: float) -> str:
    """``value`` as a user types it, text that :func:`_number` reads back as the same float: 2 for
    2.0, 0.5, 1234567.5, 1/3 and -2/3 (``{:g}``'s 0.333333 is another number, and
    0.3333333333333333 no one types); all its digits where neither 12 of them nor a fraction of a
    denominator up to 1000 is it."""
    short = f"{value:.12g}"
    if float(short) == value:
        return short
    ratio = Fraction(value).limit_denominator(1000)
    if ratio.numerator / ratio.denominator != value:
        return repr(float(value))
    return str(ratio.numerator) if ratio.denominator == 1 else f"{ratio.numerator}/{ratio.denominator}"


def _said_default(help: str) -> tuple[str, str | None]:
    """A parameter's help without its closing "; default: WHAT." and that WHAT (None when the
    help says no default), so the help page shows it where it shows every default."""
    text, sep, default = help.partition("; default: ")
    return (f"{text}.", default.rstrip(".")) if sep else (help, None)


@functools.cache
def method_options() -> dict[str, DeclaredOption]:
    """Every declared parameter of every registered method, once, in registry order."""
    return _options({method: declared(cls.Params) for method, cls in METHODS.items()})


@functools.cache
def descriptor_options() -> dict[str, DeclaredOption]:
    """Every declared parameter of every registered descriptor that one sets by a flag of its
    own (not :data:`OWN_FORMS`), once, in registry order."""
    return _options({name: [d for d in cls.options() if d.name not in OWN_FORMS] for name, cls in DESCRIPTORS.items()})


@functools.cache
def vocabulary_options() -> dict[str, DeclaredOption]:
    """How a vocabulary is made (:class:`~wiloc.bow.vocabulary_params.VocabularyParams`), one
    option of ``wiloc vocabulary`` each."""
    return _options({"vocabulary": declared(VocabularyParams)})


def _options(by_owner: Mapping[str, list[Declared]]) -> dict[str, DeclaredOption]:
    options: dict[str, dict[str, Declared]] = {}
    for owner, parameters in by_owner.items():
        for d in parameters:
            options.setdefault(d.name, {})[owner] = d
    return {name: DeclaredOption(name, owners) for name, owners in options.items()}


def _panel(option: DeclaredOption) -> str:
    owners = list(option.by_owner)
    return f"{owners[0]} options" if len(owners) == 1 else "options of " + ", ".join(owners)


def with_method_options(command: Callable[..., Any]) -> Callable[..., Any]:
    """``command`` with one keyword option per method parameter, collected into its
    ``method_options`` argument as {name: value} for the options typed on the command line."""
    return _with_options(command, method_options(), "method_options")


def with_descriptor_options(command: Callable[..., Any]) -> Callable[..., Any]:
    """``command`` with one keyword option per descriptor parameter (:func:`descriptor_options`),
    collected into its ``descriptor_options`` argument as {name: value} for the options typed on
    the command line."""
    return _with_options(command, descriptor_options(), "descriptor_options")


def with_vocabulary_options(command: Callable[..., Any]) -> Callable[..., Any]:
    """``command`` with one keyword option per vocabulary parameter (:func:`vocabulary_options`),
    collected into its ``vocabulary_options`` argument as {name: value} for the options typed on
    the command line."""
    return _with_options(command, vocabulary_options(), "vocabulary_options")


def _with_options(command: Callable[..., Any], options: dict[str, DeclaredOption],
                  argument: str) -> Callable[..., Any]:
    signature = inspect.signature(command, eval_str=True)
    static = [p for p in signature.parameters.values() if p.name != argument]
    taken = {p.name for p in static}
    generated = []
    for name, option in options.items():
        if name in taken:
            raise RuntimeError(f"declared parameter '{name}' clashes with an option of {command.__name__}")
        generated.append(inspect.Parameter(
            name, inspect.Parameter.KEYWORD_ONLY, annotation=Optional[_TYPES[option.first.kind]],
            default=typer.Option(option.default(), flag(name), help=option.help(),
                                 show_default=option.default_text(), rich_help_panel=_panel(option))))

    @functools.wraps(command)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        values = {name: kwargs.pop(name) for name in options if name in kwargs}
        return command(*args, **{argument: {k: v for k, v in values.items() if given(k)}}, **kwargs)

    wrapper.__signature__ = signature.replace(parameters=[*static, *generated])  # type: ignore[attr-defined]
    return wrapper


def method_params(method: str, given: Mapping[str, Any]) -> dict[str, Any]:
    """The parameters for ``method`` from the method options given; an option that the method
    does not take is a usage error naming the method and the methods that do take it."""
    options = method_options()
    params = {}
    for name, value in given.items():
        option = options[name]
        if method not in option.by_owner:
            takers = ", ".join(option.by_owner)
            raise UsageError(flag(name), f"method '{method}' takes no such option (it is an option of {takers})")
        params[name] = option.parse(value)
    return params


def descriptor_takers(*parameters: str) -> list[str]:
    """The registered descriptors that take any of ``parameters``."""
    return [name for name, cls in DESCRIPTORS.items() if any(d.name in parameters for d in cls.options())]


def descriptor_uses(descriptor: str, described: bool) -> dict[str, tuple[bool, str]]:
    """For ``refuse_unused``: each descriptor option (generated, or of its own form), whether
    ``descriptor`` takes it when traversals are ``described`` (not imported), and which
    descriptors do."""
    parameters = {name: [name] for name in descriptor_options()}
    for parameter, option in OWN_FORMS.items():
        parameters.setdefault(option, []).append(parameter)
    uses = {}
    for option, names in parameters.items():
        takers = descriptor_takers(*names)
        uses[option] = (described and descriptor in takers, "--descriptor " + " or ".join(takers))
    return uses


def descriptor_params(given: Mapping[str, Any]) -> dict[str, Any]:
    """The parameters for a descriptor from its generated options typed (``given``, each one it
    takes: :func:`descriptor_uses` refused the others); the library resolves the others' defaults
    (a results header records them all)."""
    return {name: descriptor_options()[name].parse(value) for name, value in given.items()}
