"""Method names -> method classes. Adding a method is one module and one line here; a method
from outside the package is put into `METHODS` before `wiloc.cli` loads, since the command line
makes its options from the registry then (docs/architecture.md, Adding a method)."""
from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from wiloc.errors import ParameterError, parameter_values
from wiloc.methods.base import Method
from wiloc.methods.catgraph.filter import CatGraph
from wiloc.methods.fabmap import FabMapMethod
from wiloc.methods.online import Online
from wiloc.methods.seqslam import SeqSLAM
from wiloc.methods.threshold import Threshold
from wiloc.methods.trained import Trained

METHODS: dict[str, type[Method]] = {
    "online": Online,
    "threshold": Threshold,
    "trained": Trained,
    "catgraph": CatGraph,
    "fabmap": FabMapMethod,
    "seqslam": SeqSLAM,
}


def method_class(name: str) -> type[Method]:
    """The class registered under ``name``; a ParameterError naming the choices otherwise, and the
    type given when it is no text (a list, None)."""
    if not isinstance(name, str):
        raise ParameterError("method", f"a method's name (text: {', '.join(METHODS)}), got {type(name).__name__}")
    if name not in METHODS:
        raise ParameterError("method", f"unknown method '{name}' (choose from {', '.join(METHODS)})")
    return METHODS[name]


def learning_from_the_map() -> list[str]:
    """The methods that read the map's differences to itself outside +-R (``exclude_recent``):
    the only ones R changes against a map."""
    return [name for name, cls in METHODS.items() if "map_self" in cls.needs]


def make_method(name: str, params: Mapping[str, Any] | None = None) -> Method:
    """A new method object of the registered ``name`` with ``params`` (defaults for the rest)."""
    return method_class(name)(parameter_values(params, "method_params"))
