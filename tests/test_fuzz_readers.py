"""Fuzz every reader with generated bad inputs: zero uncaught exceptions, every error names the file.

The bad-input classes live in :mod:`bemlearn.bench.fuzz_bench` (``bemlearn bench fuzz``
prints the same count); hypothesis draws the seeds of each class, derandomized and bounded.
Add a reader there (``register_reader`` + ``BAD_INPUTS.append``) and it is fuzzed here.
"""

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bemlearn.bench.fuzz_bench import BAD_INPUTS, format_fuzz, make_base, run_case, run_fuzz


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    root = tmp_path_factory.mktemp("fuzz")
    return root, make_base(root / "base")


@pytest.mark.parametrize("bad", BAD_INPUTS, ids=[f"{b.reader}:{b.name}" for b in BAD_INPUTS])
@settings(derandomize=True, max_examples=4, deadline=None, suppress_health_check=list(HealthCheck))
@given(seed=st.integers(min_value=0, max_value=10**6))
def test_bad_input_ends_in_a_named_error(base, bad, seed):
    root, files = base
    folder = root / f"case-{bad.reader}-{abs(hash(bad.name)) % 10**8}-{seed}"
    folder.mkdir(exist_ok=True)
    out = run_case(bad, folder, seed, files)
    assert out.named, f"{bad.reader} / {bad.name} (seed {seed}): {out.error}: {out.message}"


def test_count_of_bad_input_classes(tmp_path, capsys):
    outcomes = run_fuzz(examples=2, folder=tmp_path)
    table = format_fuzz(outcomes)
    classes = {(o.reader, o.name) for o in outcomes}
    named = {(o.reader, o.name) for o in outcomes} - {(o.reader, o.name) for o in outcomes if not o.named}
    with capsys.disabled():
        print(f"\n[fuzz] bad-input classes tried: {len(classes)}; ending in a named error: {len(named)}")
    assert len(classes) >= 80 and {r for r, _ in classes} >= {"trajectory", "config", "mjcf", "checkpoint", "torchscript", "pt2"}
    assert named == classes, table
