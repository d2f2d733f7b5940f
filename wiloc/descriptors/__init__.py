"""Whole-image descriptors (SPEC.md section 2): ``sad``, ``gist``, ``brisk-gist``, ``bow``, ``onnx``
networks, external matrices, and descriptors that installed packages register
(``DescriptorPlugin``); one class each (``Descriptor``), one registry (``DESCRIPTORS``).

Importing it loads no OpenCV, h5py or pandas (the command line builds its options from the
declarations); ``read_external`` loads its module on first use."""
from __future__ import annotations

from typing import Any

from wiloc.descriptors.base import Descriptor
from wiloc.descriptors.registry import (DESCRIPTOR_NAMES, DESCRIPTORS, METRICS, DescriptorPlugin, DescriptorSpec,
                                        descriptor_class, get_descriptor)

__all__ = ["DESCRIPTORS", "DESCRIPTOR_NAMES", "METRICS", "Descriptor", "DescriptorPlugin", "DescriptorSpec",
           "descriptor_class", "get_descriptor", "read_external"]


def __getattr__(name: str) -> Any:
    if name == "read_external":
        from wiloc.descriptors.external import read_external
        return read_external
    raise AttributeError(f"module 'wiloc.descriptors' has no attribute {name!r}")
