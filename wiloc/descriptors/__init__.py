"""Whole-image descriptors (SPEC.md section 2): ``sad``, ``gist``, ``brisk-gist``, ``onnx`` networks,
external matrices, and descriptors that installed packages register (``DescriptorPlugin``)."""
from __future__ import annotations

from wiloc.descriptors.external import read_external
from wiloc.descriptors.registry import DESCRIPTOR_NAMES, METRICS, DescriptorPlugin, DescriptorSpec, get_descriptor

__all__ = ["DESCRIPTOR_NAMES", "METRICS", "DescriptorPlugin", "DescriptorSpec", "get_descriptor", "read_external"]
