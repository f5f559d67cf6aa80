"""The heap's free pages handed back to the system (base.heap)."""
import numpy as np
import pytest

from base import heap


def _rss() -> int:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * 4096


@pytest.mark.skipif(heap._TRIM is None, reason="the C library has no malloc_trim (not glibc)")
def test_free_pages_inside_the_heap_go_back_to_the_system():
    """64 MiB of 64 KiB arrays (in the heap, below glibc's mmap threshold), every other
    one freed: the freed half stays resident, between live arrays, until
    release_free_pages hands it back; below MIN_ROWS rows nothing is done."""
    assert not heap.release_free_pages(heap.MIN_ROWS - 1)
    blocks = [np.ones(8192) for _ in range(1024)]
    kept = blocks[1::2]
    del blocks
    before = _rss()
    assert heap.release_free_pages(heap.MIN_ROWS)
    assert before - _rss() > 24 * 2**20
    assert all(float(b[-1]) == 1.0 for b in kept)  # the live arrays are untouched
