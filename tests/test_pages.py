"""Float arrays in huge pages (pgdcli.pages): shapes, alignment, lifetime, the fallback."""

from __future__ import annotations

import gc
import mmap

import numpy as np
import pytest

from pgdcli import pages


@pytest.mark.parametrize("values", [1, 1000, 300_000, (1 << 21) // 8, (1 << 21) // 8 + 1])
def test_huge_page_array_is_aligned_writable_and_outlives_its_mapping_name(values):
    a = pages.huge_page_array(values)
    assert a.shape == (values,) and a.dtype == np.float64 and a.flags.writeable and a.flags.c_contiguous
    if hasattr(mmap, "MADV_HUGEPAGE"):
        assert a.ctypes.data % pages.HUGE_PAGE == 0  # the first huge page starts at the array
    a[:] = np.arange(values)
    view = a[values // 2:]
    del a
    gc.collect()  # the mapping lives as long as a view of it
    assert view[0] == values // 2 and view[-1] == values - 1


def test_without_madvise_it_is_a_numpy_array(monkeypatch):
    monkeypatch.delattr(mmap, "MADV_HUGEPAGE", raising=False)
    a = pages.huge_page_array(10)
    assert a.shape == (10,) and a.base is None  # a plain numpy allocation
