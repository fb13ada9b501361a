"""bemlearn.threads.torch_threads: the count inside the block, the previous one after it (also after an error)."""

from __future__ import annotations

import pytest
import torch

from bemlearn.errors import ArgumentError
from bemlearn.threads import torch_threads


def test_the_count_is_set_inside_and_restored_after_also_on_error():
    before = torch.get_num_threads()
    other = 1 if before != 1 else 2
    with torch_threads(other):
        assert torch.get_num_threads() == other
    assert torch.get_num_threads() == before
    with pytest.raises(RuntimeError, match="inside"), torch_threads(other):
        raise RuntimeError("inside")
    assert torch.get_num_threads() == before
    with torch_threads(None):
        assert torch.get_num_threads() == before
    with pytest.raises(ArgumentError, match="threads: expected a positive integer, got 0"), torch_threads(0):
        pass
    assert torch.get_num_threads() == before
