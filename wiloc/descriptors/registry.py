"""Descriptor names -> descriptor classes. Adding a descriptor is one module and one line here.

Besides the built-in descriptors, installed packages may register their own under the entry-point
group ``wiloc.descriptors`` (:class:`DescriptorPlugin`); they are loaded on first use of a name
that is not registered, or when the descriptors are listed, and registered here too.
"""
from __future__ import annotations

import functools
import json
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from typing import Any

import numpy as np
from numpy.typing import NDArray

from wiloc.descriptors.base import (BUILT_IN, METRICS, ComputeError, Descriptor, DescriptorSpec, check_names,
                                    checked_storage, scale_and_max)
from wiloc.descriptors.bow import Bow
from wiloc.descriptors.brisk_gist import BriskGist
from wiloc.descriptors.gist import Gist
from wiloc.descriptors.learned import Onnx
from wiloc.descriptors.sad import Sad
from wiloc.errors import ParameterError

PLUGIN_GROUP = "wiloc.descriptors"


class External(Descriptor):
    """A user's matrix, imported, never computed: ``metric`` and ``length`` required; ``dtype``
    uint8 for hamming."""

    name = "external"
    depends = "the imported matrix"
    libraries = ()  # read from the user's file, computed by no library of this environment
    imported = True

    @classmethod
    def make(cls, given: Mapping[str, Any]) -> DescriptorSpec:
        check_names(cls.name, given, ("metric", "length", "dtype"))
        p = {"metric": None, "length": None, "dtype": "float32", **given}
        metric, length, dtype = checked_storage("external", p["metric"], p["length"], p["dtype"])
        p["dtype"] = dtype.name
        scale, natural_max = scale_and_max(metric, length)
        return cls._spec(p, metric=metric, dtype=dtype, length=length, scale=scale, min_size=None,
                         natural_max=natural_max)


#: The one registry: every descriptor by name, built-in ones first, then the plugins as they load.
DESCRIPTORS: dict[str, type[Descriptor]] = {
    "sad": Sad,
    "gist": Gist,
    "brisk-gist": BriskGist,
    "bow": Bow,
    "onnx": Onnx,
    "external": External,
}
#: The built-in descriptors any image folder can be described with, no file needed.
DESCRIPTOR_NAMES = tuple(name for name, cls in DESCRIPTORS.items() if not cls.depends)


def descriptor_class(name: str) -> type[Descriptor]:
    """The class registered under ``name`` (installed plugins loaded first when it is not); a
    ValueError naming the choices otherwise, a ParameterError naming ``descriptor`` and the type
    given when it is no text (a list)."""
    if not isinstance(name, str):
        raise ParameterError("descriptor", f"a descriptor's name (text: {', '.join(DESCRIPTOR_NAMES)}, ...), "
                                           f"got {type(name).__name__}")
    if name not in DESCRIPTORS:
        plugins = _plugins()
        if name not in DESCRIPTORS:
            choices = ", ".join(n for n in DESCRIPTORS if n != External.name)
            failed = next((f"; {problem}" for problem in plugins.problems if f"'{name}'" in problem), "")
            raise ValueError(f"unknown descriptor {name!r}; choose one of {choices}{failed}")
    return DESCRIPTORS[name]


def get_descriptor(name: str, **params: Any) -> DescriptorSpec:
    """The spec of a named descriptor with the given parameters (defaults for the rest).

    ``external`` describes an imported matrix: ``get_descriptor("external", metric="cosine",
    length=D, dtype="float32")``; ``bow`` a vocabulary's word presence:
    ``get_descriptor("bow", file=VOCABULARY_H5)``; ``onnx`` a network's vectors:
    ``get_descriptor("onnx", model=MODEL_ONNX)``. Other names are looked up among the
    installed plugins (:class:`DescriptorPlugin`).
    """
    return descriptor_class(name).make(params)


# -------------------------------------------------------------------------------------------- plugins

@dataclass(frozen=True)
class DescriptorPlugin:
    """A descriptor that an installed package registers: the value of an entry point in the group
    ``wiloc.descriptors`` (the entry point's name is the descriptor's name). In its pyproject.toml::

        [project.entry-points."wiloc.descriptors"]
        tiny = "tiny_descriptor:TINY"     # TINY = DescriptorPlugin(compute=..., metric="l1", length=64)

    ``compute(gray, **params)`` gives the descriptor of one 8-bit grayscale image (H x W) as a flat
    ``(length,)`` array of ``dtype`` (packed bits, uint8, for ``hamming``); ``params`` are its
    parameters and their defaults (JSON values). It runs in worker processes too, each of which
    loads the plugin from its entry point (a spec pickles its class by name). The cache keys its
    results by name, parameters and the package's version, so a new release of the package
    computes afresh.
    """

    compute: Callable[..., NDArray]
    metric: str
    length: int
    dtype: str = "float32"
    params: Mapping[str, Any] = field(default_factory=dict)


class PluginDescriptor(Descriptor):
    """A registered plugin's descriptor: its parameters are the plugin's, plus ``plugin`` (the
    package's ``distribution version``), so a new release computes afresh."""

    plugin: DescriptorPlugin

    @classmethod
    def make(cls, given: Mapping[str, Any]) -> DescriptorSpec:
        plugin = cls.plugin
        metric, length, dtype = checked_storage(cls.name, plugin.metric, plugin.length, plugin.dtype)
        defaults = {**plugin.params, "plugin": cls.source}
        check_names(cls.name, given, list(defaults))
        p = {**defaults, **given}
        if p["plugin"] != cls.source:
            raise ValueError(f"{cls.name}: described by {p['plugin']}, but {cls.source} is installed")
        scale, natural_max = scale_and_max(metric, length)
        return cls._spec(p, metric=metric, dtype=dtype, length=length, scale=scale, min_size=None,
                         natural_max=natural_max)

    @classmethod
    def compute(cls, image: NDArray[np.uint8], params: Mapping[str, Any]) -> NDArray:
        """The plugin's descriptor of ``image``; whatever its code raises is a ComputeError naming
        it (and its package), not the plugin's traceback."""
        try:
            return cls.plugin.compute(image, **{k: params[k] for k in cls.plugin.params})
        except Exception as exc:  # noqa: BLE001 - anything third-party code may raise
            raise ComputeError(cls.shown(), _said(exc)) from None


@dataclass(frozen=True)
class _Plugins:
    found: dict[str, str]  # name -> where it came from (``distribution version``)
    problems: tuple[str, ...]  # one line per plugin that could not be loaded, naming it


@functools.cache
def _plugins() -> _Plugins:
    """The installed descriptor plugins, loaded and registered once per process; a plugin that
    fails to load, or registers something that cannot work, is left out with one line saying why."""
    found: dict[str, str] = {}
    problems: list[str] = []
    for point in entry_points(group=PLUGIN_GROUP):
        origin = f"{point.dist.name} {point.dist.version}" if point.dist is not None else point.value
        where = f"descriptor plugin '{point.name}' ({origin})"
        if point.name in DESCRIPTORS:
            taken = DESCRIPTORS[point.name].source
            problems.append(f"{where}: the name is taken by "
                            f"{'a built-in descriptor' if taken == BUILT_IN else taken}; left out")
            continue
        try:
            plugin = point.load()
            if not isinstance(plugin, DescriptorPlugin):
                raise TypeError(f"{point.value} is a {type(plugin).__name__}, not a wiloc DescriptorPlugin")
            if not callable(plugin.compute):
                raise TypeError("its compute is not callable")
            checked_storage(point.name, plugin.metric, plugin.length, plugin.dtype)
            json.dumps(dict(plugin.params))
            if "plugin" in plugin.params:
                raise ValueError("'plugin' is wiloc's parameter (the package's version); name yours otherwise")
        except Exception as exc:  # anything a third-party import or declaration may raise
            problems.append(f"{where} failed to load: {_said(exc)}")
            continue
        DESCRIPTORS[point.name] = type(_plugin_class_name(point.name), (PluginDescriptor,), {
            "__module__": __name__, "name": point.name, "metric": plugin.metric, "source": origin,
            "plugin": plugin})
        found[point.name] = origin
    return _Plugins(found, tuple(problems))


def _said(exc: Exception) -> str:
    """A plugin's exception in one line: its class and its message's first line."""
    lines = str(exc).strip().splitlines()
    return f"{type(exc).__name__}{': ' + lines[0] if lines else ''}"


def _plugin_class_name(name: str) -> str:
    """What the class of plugin ``name`` is called, in this module: ``Plugin[NAME]``."""
    return f"Plugin[{name}]"


def __getattr__(attribute: str) -> type[Descriptor]:
    """A plugin's class by its name in this module (PEP 562), the installed plugins loaded first.

    The classes are made as the plugins load, so pickle (a spec sent to a worker process, or to
    a Dask worker by cloudpickle) can find one by name only here; a worker that unpickles it
    loads the plugins itself, from their entry points, and computes with the very same code."""
    name = attribute.removeprefix("Plugin[").removesuffix("]")
    if attribute == _plugin_class_name(name) and name not in DESCRIPTORS:
        _plugins()
    found = DESCRIPTORS.get(name)
    if found is None or found.__qualname__ != attribute:
        raise AttributeError(f"module {__name__!r} has no attribute {attribute!r}")
    return found


def plugin_named(problem: str) -> str | None:
    """The name of the descriptor plugin whose class ``problem`` names, as pickle's words do where
    the plugin is not installed ("Can't get attribute 'Plugin[NAME]' on ..."); else None."""
    found = re.search(r"'Plugin\[(.+?)\]'", problem)
    return found[1] if found else None


def plugin_problems() -> tuple[str, ...]:
    """One line per installed descriptor plugin that could not be loaded, naming it and why."""
    return _plugins().problems


@dataclass(frozen=True)
class DescriptorInfo:
    """One descriptor as ``describe --list-descriptors`` shows it: where it comes from
    (``built-in``, or a plugin's ``distribution version``), its metric and its length where
    they do not depend on its parameters (else None, and ``depends`` says on what)."""

    name: str
    source: str
    metric: str | None
    length: int | None
    depends: str = ""


def available_descriptors() -> list[DescriptorInfo]:
    """Every descriptor wiloc can compute or import, in registry order: the built-in ones, then
    the plugins."""
    _plugins()
    infos = []
    for name, cls in DESCRIPTORS.items():
        if cls.depends:
            infos.append(DescriptorInfo(name, cls.source, cls.metric, None, cls.depends))
        else:
            spec = cls.make({})
            infos.append(DescriptorInfo(name, cls.source, spec.metric, spec.length))
    return infos


__all__ = ["BUILT_IN", "DESCRIPTORS", "DESCRIPTOR_NAMES", "METRICS", "DescriptorPlugin", "DescriptorSpec",
           "descriptor_class", "get_descriptor", "plugin_problems", "available_descriptors"]
