"""Shared fixtures: deterministic seeds, restored global torch state."""

from __future__ import annotations

import random

import numpy as np
import pytest
import torch


@pytest.fixture(autouse=True)
def _deterministic():
    """Seed every generator and restore torch's global defaults after each test."""
    dtype = torch.get_default_dtype()
    threads = torch.get_num_threads()
    random.seed(0)
    np.random.seed(0)
    torch.manual_seed(0)
    yield
    assert torch.get_default_dtype() == dtype, "a test changed torch's default dtype"
    torch.set_default_dtype(dtype)
    torch.set_num_threads(threads)


FURUTA_CONFIG = __import__("pathlib").Path(__file__).resolve().parents[1] / "configs" / "furuta.yaml"


def furuta_section(name: str, **overrides):
    """A section of the shipped ``configs/furuta.yaml`` (resolved), with ``overrides`` replaced."""
    import dataclasses

    from bemlearn.pipeline.resolve import load_pipeline_config

    return dataclasses.replace(getattr(load_pipeline_config(FURUTA_CONFIG), name), **overrides)
