"""keep_freed_memory: large blocks come from the heap and are reused, not mapped afresh."""

from __future__ import annotations

import resource
import sys

import pytest
import torch

from granular_pyg.heap import keep_freed_memory


def _minor_faults_of_a_fresh_tensor(megabytes: int) -> int:
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    x = torch.empty(megabytes * 2**18)  # float32
    x.fill_(1.0)  # touch every page
    del x
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_a_freed_large_tensor_is_reused_without_new_page_faults():
    assert keep_freed_memory() is True
    assert keep_freed_memory() is True  # idempotent
    _minor_faults_of_a_fresh_tensor(128)  # the heap grows once, to hold the largest block
    # 64 MB (above glibc's largest mmap threshold, 32 MB) is 16,384 pages of 4 kB: a fresh
    # mapping faults on each of them; memory the heap kept faults on none
    assert _minor_faults_of_a_fresh_tensor(64) < 1_000


def test_the_environment_variable_turns_it_off(monkeypatch):
    import granular_pyg.heap as heap

    def no_libc(*args, **kwargs):
        raise AssertionError("malloc was asked to keep freed memory")

    monkeypatch.setattr(heap, "_done", False)
    monkeypatch.setattr(heap.ctypes, "CDLL", no_libc)
    for off in ("0", "false", "OFF"):
        monkeypatch.setenv(heap.ENV_VAR, off)
        assert keep_freed_memory() is False
    monkeypatch.setenv(heap.ENV_VAR, "1")
    with pytest.raises(AssertionError, match="keep freed memory"):
        keep_freed_memory()
