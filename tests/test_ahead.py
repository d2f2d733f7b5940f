"""Tests of the helper thread that computes a pipeline's items ahead of its caller."""
from __future__ import annotations

import os
import sys
import threading

import pytest

from wiloc.ahead import HELPER_NICE, computed_ahead


def _nice_here() -> int:
    return os.getpriority(os.PRIO_PROCESS, threading.get_native_id())


def test_items_arrive_in_order_and_an_error_arrives_in_its_place() -> None:
    def items():
        yield from range(5)
        raise ValueError("item 5 failed")

    seen = []
    with pytest.raises(ValueError, match="item 5 failed"):
        for item in computed_ahead(items()):
            seen.append(item)  # noqa: PERF402 - keeps the items before the error
    assert seen == [0, 1, 2, 3, 4]


@pytest.mark.skipif(sys.platform != "linux", reason="thread priorities are per thread on Linux only")
def test_helpers_run_below_the_callers_priority_and_nested_helpers_at_the_same_level() -> None:
    main = os.getpriority(os.PRIO_PROCESS, os.getpid())
    want = min(main + HELPER_NICE, 19)

    def inner():
        yield _nice_here()

    def outer():
        for nested in computed_ahead(inner()):  # a helper started by a helper
            yield _nice_here(), nested

    assert list(computed_ahead(outer())) == [(want, want)]
    assert _nice_here() == main  # the caller's own priority is untouched
