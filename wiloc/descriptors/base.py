"""What every descriptor is: a class naming it, declaring its parameters (a frozen
:class:`~wiloc.parameters.Parameters` dataclass) and saying how it is stored, compared and computed;
and :class:`DescriptorSpec`, one descriptor with fixed parameters, as the pipeline carries it.

A spec holds data (name, parameters, storage facts) and the class that made it, which pickles
by name (a plugin's too, through the registry), so a spec pickles cheaply into worker processes.
Its ``params`` hold every parameter (defaults filled in), so equal descriptors give equal cache
keys. This module, and every
descriptor's declarations, load without OpenCV: the command line builds its options from them.
"""
from __future__ import annotations

import functools
import importlib
import json
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from wiloc.errors import ParameterError, WilocError
from wiloc.parameters import Declared, Parameters, declared

METRICS = ("l1", "sqeuclidean", "hamming", "cosine")
BUILT_IN = "built-in"
#: The libraries whose computation a descriptor's rows may depend on (``Descriptor.libraries``),
#: by the name a cache key gives them, each with the module whose ``__version__`` says its version.
LIBRARIES = {"opencv": "cv2", "onnxruntime": "onnxruntime"}


@functools.cache
def library_version(name: str) -> str:
    """The version of library ``name`` (one of LIBRARIES) in this environment, imported now: the
    declarations load without it."""
    return str(importlib.import_module(LIBRARIES[name]).__version__)


def library_versions(names: Iterable[str]) -> dict[str, str]:
    """``{name: version}`` of the libraries ``names`` (:func:`library_version`): what the cache keys
    rows computed by them by, so that environments sharing a cache never mix their rows."""
    return {name: library_version(name) for name in names}


@dataclass(frozen=True)
class DescriptorSpec:
    """Everything the pipeline needs to know about one descriptor with fixed parameters."""

    name: str
    params: Mapping[str, Any]
    metric: str
    dtype: np.dtype
    length: int
    scale: float
    min_size: tuple[int, int] | None
    natural_max: float | None
    kind: type[Descriptor] = field(compare=False, repr=False)  # the registered class that made it
    colour: bool = False  # computed from 8-bit BGR images (H x W x 3), in batches: ``compute_batch``

    @property
    def cache_params(self) -> dict[str, Any]:
        """What the cache keys an entry by: the parameters, the version of the class's computation
        (``Descriptor.version``) and those of the libraries it computes with
        (``Descriptor.libraries``), so that rows computed otherwise are never reused."""
        return {**self.params, "code_version": self.kind.version,
                "libraries": library_versions(self.kind.libraries)}

    @property
    def key(self) -> str:
        """Canonical JSON of name and parameters: equal descriptors give equal keys (the cache keys
        entries by :attr:`cache_params`)."""
        return json.dumps({"name": self.name, "params": dict(self.params)}, sort_keys=True)

    def compute(self, image: NDArray[np.uint8]) -> NDArray:
        """Descriptor of one 8-bit image, flat, ``(length,)`` of ``dtype``: grayscale (H x W), or
        BGR (H x W x 3) for a ``colour`` descriptor."""
        if self.colour:
            return self.compute_batch([image])[0]
        return self._checked(self.kind.compute(self._image(image), self.params), (self.length,))

    @property
    def feature_setting(self) -> dict[str, Any] | None:
        """For a descriptor computed from an image's local features (``bow``), how they are
        extracted (``wiloc.bow.features.extract_features``' keyword arguments); else None."""
        return self.kind.feature_setting(self.params)

    def compute_from_features(self, features: NDArray) -> NDArray:
        """Descriptor of one image from its local features (as :attr:`feature_setting` extracts
        them), flat, ``(length,)`` of ``dtype``: what :meth:`compute` gives from its pixels."""
        return self._checked(self.kind.from_features(features, self.params), (self.length,))

    def compute_batch(self, images: Sequence[NDArray[np.uint8]], threads: int = 0) -> NDArray:
        """Descriptors of several images, one row each: a ``colour`` descriptor's network runs
        them in batches on ``threads`` threads (0: its runtime's default); the others are
        computed one by one."""
        if self.colour:
            return self._checked(self.kind.compute_batch([self._image(image) for image in images], self.params,
                                                         threads), (len(images), self.length))
        return np.stack([self.compute(image) for image in images])

    def _image(self, image: Any) -> NDArray[np.uint8]:
        """``image`` checked to be what the descriptor is computed from, else a WilocError naming
        the descriptor: an 8-bit gray image (a ``colour`` descriptor's: BGR), not empty; a float
        image in [0, 1] gave other values, a colour one a Python or OpenCV error
        (``Localizer.describe`` converts such arrays)."""
        image = np.asarray(image)
        wanted, shape_ok = ("BGR (H x W x 3)", image.ndim == 3 and image.shape[2] == 3) if self.colour else \
            ("gray (H x W)", image.ndim == 2)
        if image.dtype != np.uint8 or not shape_ok or image.size == 0:
            raise WilocError(f"descriptor '{self.name}'", f"computed from an 8-bit {wanted} image, not empty; got "
                                                          f"{image.dtype} values of shape {image.shape} (Localizer."
                                                          f"describe converts other images)")
        return image

    def _checked(self, computed: Any, shape: tuple[int, ...]) -> NDArray:
        """What the descriptor's class computed, as ``dtype``: of the ``shape`` it declares and
        finite, else a WilocError naming the descriptor (a plugin's row of another length was a
        numpy broadcasting error, its NaN rows were cached and compared as they were)."""
        where = self.kind.shown()
        with np.errstate(over="ignore"):  # beyond float32's range: refused below
            rows = np.asarray(computed, dtype=self.dtype)
        if rows.shape != shape:
            raise WilocError(where, f"computed an array of shape {rows.shape}; it declares {self.length} values "
                                    f"per image, a flat row")
        if rows.dtype.kind == "f" and not np.isfinite(rows).all():
            raise WilocError(where, "computed NaN or infinite values")
        return rows


class ComputeError(WilocError):
    """A descriptor's own code (a plugin's) raised ``error`` (its class and first line) computing
    an image: one line naming the descriptor, and the frame once it is known (:meth:`on`)."""

    def __init__(self, where: str, error: str, frame: str | None = None) -> None:
        super().__init__(where, f"failed{f' on {frame}' if frame else ''}: {error}")
        self.error = error

    def on(self, frame: str) -> ComputeError:
        """This failure said of the frame ``frame`` (its file's name) it happened on."""
        return ComputeError(self.where, self.error, frame)


@dataclass(frozen=True)
class NoParams(Parameters):
    """The parameters of a descriptor that has none."""


class Descriptor:
    """A descriptor: its name, its declared ``Params`` and how it is stored and computed.

    Adding one is a module with a subclass and one line in ``wiloc.descriptors.registry``. A
    subclass sets the class attributes and implements :meth:`spec` (from its complete parameters:
    dtype, length, scale, smallest decode size, natural maximum) and :meth:`compute` (or
    :meth:`compute_batch` for ``colour`` descriptors); one whose parameters name a file it reads
    (``bow``, ``onnx``) overrides :meth:`make` instead of :meth:`spec`.
    """

    name: ClassVar[str] = ""
    Params: ClassVar[type[Parameters]] = NoParams
    metric: ClassVar[str | None] = None  # None: it depends (``depends`` says on what)
    depends: ClassVar[str] = ""  # what its metric and length depend on ("" when fixed by its parameters)
    source: ClassVar[str] = BUILT_IN  # or a plugin's "distribution version"
    colour: ClassVar[bool] = False  # computed from colour images, in batches
    words: ClassVar[bool] = False  # visual word presence: methods reading FAB-MAP's evidence take it
    derived: ClassVar[tuple[str, ...]] = ()  # parameters read from its files (given, they must agree)
    #: How its rows are computed: raised with any change to the computation that moves a row, so
    #: that the cache describes afresh what an earlier version computed (its entries' key holds it).
    version: ClassVar[int] = 1
    #: The libraries (names in LIBRARIES) its rows depend on beyond wiloc's code, whose versions its
    #: entries' key holds: OpenCV decodes and resizes every image described.
    libraries: ClassVar[tuple[str, ...]] = ("opencv",)
    #: Its rows are imported, never computed from an image (``external``): a map of them takes rows.
    imported: ClassVar[bool] = False

    @classmethod
    def shown(cls) -> str:
        """How errors name it: ``descriptor 'NAME'``, a plugin's followed by its package's
        ``(distribution version)``."""
        return f"descriptor '{cls.name}'" + ("" if cls.source == BUILT_IN else f" ({cls.source})")

    @classmethod
    def options(cls) -> list[Declared]:
        """The declared parameters one sets (``derived`` ones left out), in field order."""
        return [d for d in declared(cls.Params) if d.name not in cls.derived]

    @classmethod
    def complete(cls, given: Mapping[str, Any]) -> dict[str, Any]:
        """Every parameter, checked against the declarations, as JSON-ready values (what the
        cache key holds): a ParameterError naming the first one that cannot work."""
        check_names(cls.name, given, [d.name for d in declared(cls.Params)])
        values = cls.Params(**given).as_dict()
        for d in declared(cls.Params):  # an int given for a float parameter is stored as the float
            if d.kind == "float" and values[d.name] is not None:
                values[d.name] = float(values[d.name])
        return values

    @classmethod
    def make(cls, given: Mapping[str, Any]) -> DescriptorSpec:
        """The spec of this descriptor with the ``given`` parameters (defaults for the rest)."""
        return cls.spec(cls.complete(given))

    @classmethod
    def spec(cls, params: dict[str, Any]) -> DescriptorSpec:
        """The spec for complete, checked parameters."""
        raise NotImplementedError

    @classmethod
    def compute(cls, image: NDArray[np.uint8], params: Mapping[str, Any]) -> NDArray:
        """The descriptor of one 8-bit grayscale image (H x W), flat."""
        raise TypeError(f"'{cls.name}' descriptors are imported, not computed")

    @classmethod
    def compute_batch(cls, images: Sequence[NDArray[np.uint8]], params: Mapping[str, Any],
                      threads: int) -> NDArray:
        """The descriptors of several 8-bit BGR images (``colour`` descriptors), one row each."""
        raise NotImplementedError

    @classmethod
    def feature_setting(cls, params: Mapping[str, Any]) -> dict[str, Any] | None:
        """For a descriptor computed from local features: how they are extracted
        (``extract_features``' keyword arguments), so that describing keeps them in the cache and
        computes from the ones it holds (:meth:`from_features`); None (the default) for the others."""
        return None

    @classmethod
    def from_features(cls, features: NDArray, params: Mapping[str, Any]) -> NDArray:
        """The descriptor of one image from its local features (see :meth:`feature_setting`), flat."""
        raise NotImplementedError

    @classmethod
    def doubts(cls, params: Mapping[str, Any]) -> list[str]:
        """Warnings that hold for every result of this descriptor with these parameters."""
        return []

    @classmethod
    def traversal_doubts(cls, data: NDArray, params: Mapping[str, Any]) -> list[str]:
        """Warnings about one traversal's descriptors (``data``, a row per frame), each said of
        the traversal ("its 200 images ..."): none by default."""
        return []

    @classmethod
    def _spec(cls, params: dict[str, Any], **storage: Any) -> DescriptorSpec:
        """A spec of this class's name, metric and colour, with the storage facts given."""
        return DescriptorSpec(name=cls.name, params=params, metric=storage.pop("metric", cls.metric),
                              kind=cls, colour=cls.colour, **storage)


def check_names(name: str, given: Mapping[str, Any], valid: Sequence[str]) -> None:
    """A ParameterError naming the first parameter in ``given`` that descriptor ``name`` does not
    take and listing those it does, as a method's parameters are refused."""
    unknown = sorted(set(given) - set(valid))
    if unknown:
        raise ParameterError(unknown[0], f"not a parameter of descriptor '{name}' (valid: {', '.join(valid) or 'none'})")


def scale_and_max(metric: str, length: int) -> tuple[float, float | None]:
    """Scale and natural maximum of a descriptor of `length` values compared by `metric`, where
    nothing else is known of it (an imported matrix, a network's vectors, a plugin's)."""
    scales = {"l1": 1.0 / length, "sqeuclidean": 1.0, "hamming": 1.0, "cosine": 1.0}
    maxima = {"l1": None, "sqeuclidean": None, "hamming": 8.0 * length, "cosine": 2.0}
    return scales[metric], maxima[metric]


def checked_storage(what: str, metric: Any, length: Any, dtype: Any) -> tuple[str, int, np.dtype]:
    """A descriptor's metric, length and dtype, checked: a metric of METRICS, a positive length,
    packed bits (uint8) for hamming and floats for the others."""
    if metric not in METRICS:
        raise ValueError(f"{what} metric must be one of {', '.join(map(repr, METRICS))}; got {metric!r}")
    if isinstance(length, bool) or not isinstance(length, int) or length < 1:
        raise ValueError(f"{what} length must be a positive integer; got {length!r}")
    dtype = np.dtype(dtype)
    if dtype != np.uint8 if metric == "hamming" else dtype.kind != "f":
        raise ValueError(f"{what} dtype {dtype.name}: hamming descriptors are packed bits (uint8); other metrics "
                         "need floats")
    return metric, length, dtype
