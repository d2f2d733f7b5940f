"""The `wiloc` command line: parse options, call wiloc.api, render rich tables or JSON.

It loads quickly (``wiloc --help`` answers without pandas, scipy, h5py or OpenCV): the commands
import wiloc.api when they run. One module per command (``describe``, ``vocabulary``,
``localize`` with ``localize_views``, ``evaluate``, ``compare``, ``report``, ``demo``),
grouped in ``commands``; what they share is in ``core`` (errors, parsing), ``params`` (options
made from declared parameters), ``options``, ``truth`` (the --gt grammar), ``scoring`` and
``views`` (tables, JSON, progress).
"""
from __future__ import annotations

from wiloc.cli.commands import app, run

__all__ = ["app", "run"]
