"""Arrays whose memory serves again (wiloc.recycled)."""
from __future__ import annotations

import numpy as np
import pytest

from wiloc.recycled import RecycledArrays


def address(array: np.ndarray) -> int:
    return array.__array_interface__["data"][0]


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_memory_serves_again_only_once_no_view_of_it_is_left(dtype: type) -> None:
    arrays = RecycledArrays(dtype)
    first = arrays.take((3, 4))
    first[:] = 1.0
    at = address(first)
    row = first[1]  # a view outlives the array it came from
    del first
    second = arrays.take((3, 4))
    assert address(second) != at  # still in use: fresh memory
    second[:] = 2.0
    assert row.tolist() == [1.0] * 4
    del row
    third = arrays.take((2, 4))  # smaller: the free memory serves, C-contiguous, of the dtype
    assert address(third) == at
    assert third.shape == (2, 4) and third.dtype == dtype and third.flags.c_contiguous and third.flags.writeable
    del second, third
    larger = arrays.take((4, 4))  # larger than any free memory: fresh
    assert address(larger) != at and larger.shape == (4, 4)


def test_a_sorted_view_keeps_its_memory_until_it_goes() -> None:
    arrays = RecycledArrays(np.float32)
    values = arrays.take((2, 5))
    values[:] = [[3, 1, 2, 5, 4], [9, 8, 7, 6, 5]]
    values.sort(axis=1)
    kept = values[0]
    at = address(values)
    del values
    assert address(arrays.take((2, 5))) != at and kept.tolist() == [1, 2, 3, 4, 5]
