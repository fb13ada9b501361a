"""Shared preamble of the "loads without bemlearn" subprocess tests: block every bemlearn import."""

BLOCK_BEMLEARN = """
import json, sys

class _NoBemlearn:
    def find_spec(self, name, path=None, target=None):
        if name == "bemlearn" or name.startswith("bemlearn."):
            raise ImportError("bemlearn is blocked in this process")
        return None

sys.meta_path.insert(0, _NoBemlearn())
import torch

torch.set_num_threads(1)  # as the test process (tests/conftest.py): the same reductions, so the same bits
"""
