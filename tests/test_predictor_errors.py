"""Every documented input error of both artifacts, as it surfaces in a process without bemlearn.

docs/predictor-contract.md ("Errors") lists, per artifact, the exception class a controller
must catch and the message; this test loads each file with plain torch (bemlearn blocked),
feeds each bad input and checks the class (by its MRO) and message, and checks that
bemlearn's own ``.pt2`` loader raises the same ``PredictorInputError`` messages as the
TorchScript module.
"""

import json
import os
import subprocess
import sys
import textwrap

import pytest
import torch

from bemlearn.bench.predict_bench import synthetic_posterior
from bemlearn.errors import BemlearnError, PredictorInputError
from bemlearn.export import BEMPredictor, load_pt2_predictor, save_pt2, save_torchscript
from tests.isolation import BLOCK_BEMLEARN

F64 = torch.float64

#: bad input → (TorchScript: (class, message part), raw .pt2 program: (class, message part)); m = 1, width 3.
CASES = {
    "rank1": ("torch.zeros(3, dtype=torch.float64)", ("Error", "expected x of shape (B, 3)"), ("IndexError", "")),
    "rank3": ("torch.zeros(2, 3, 1, dtype=torch.float64)", ("Error", "expected x of shape (B, 3)"), ("RuntimeError", "")),
    "width": ("torch.zeros(2, 4, dtype=torch.float64)", ("Error", "got shape [2, 4]"), ("AssertionError", "x.size()[1] == 3")),
    "dtype": ("torch.zeros(2, 3)", ("Error", "dtype torch.float32"), ("RuntimeError", "Tensor dtype mismatch")),
    "empty": ("torch.zeros(0, 3, dtype=torch.float64)", ("Error", "got shape [0, 3]"), ("RuntimeError", "empty batch (B = 0)")),
    "nan": ("torch.tensor([[0.0, float('nan'), 0.0]], dtype=torch.float64)", ("Error", "x[0, 1] is nan"), ("RuntimeError", "non-finite entries")),
    "inf": ("torch.tensor([[0.0, 0.0, float('-inf')]], dtype=torch.float64)", ("Error", "x[0, 2] is -inf"), ("RuntimeError", "non-finite entries")),
}

_SCRIPT = BLOCK_BEMLEARN + textwrap.dedent(
    """
    cases = json.loads(sys.argv[1])
    ts = torch.jit.load("bem_predictor.pt")
    pt2 = torch.export.load("bem_predictor.pt2").module()
    out = {}
    for name, expr in cases.items():
        x = eval(expr)
        row = {}
        for art, fn in (("pt", ts), ("pt2", pt2)):
            try:
                fn(x)
                row[art] = None
            except Exception as exc:
                row[art] = [[c.__name__ for c in type(exc).__mro__], str(exc)]
        out[name] = row
    assert not any(m == "bemlearn" or m.startswith("bemlearn.") for m in sys.modules)
    print(json.dumps(out))
    """
)


@pytest.fixture(scope="module")
def artifacts(tmp_path_factory):
    state, meta = synthetic_posterior(n_train=60, m=1, seed=3)
    eager = BEMPredictor(state, meta)
    root = tmp_path_factory.mktemp("artifacts")
    save_torchscript(eager, root / "bem_predictor.pt")
    save_pt2(eager, root / "bem_predictor.pt2")
    return root


@pytest.fixture(scope="module")
def isolated(artifacts):
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    done = subprocess.run(
        [sys.executable, "-I", "-W", "ignore", "-c", _SCRIPT, json.dumps({k: v[0] for k, v in CASES.items()})],
        cwd=artifacts, env=env, capture_output=True, text=True, timeout=300,
    )
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


@pytest.mark.parametrize("case", sorted(CASES))
def test_torchscript_error_as_documented(isolated, case):
    mro, msg = isolated[case]["pt"]
    assert mro[0] == "Error" and "RuntimeError" not in mro and "ValueError" not in mro, mro  # torch.jit.Error(Exception)
    assert "ValueError: BEMPredictor.forward:" in msg and CASES[case][1][1] in msg, msg


@pytest.mark.parametrize("case", sorted(CASES))
def test_raw_pt2_error_as_documented(isolated, case):
    got = isolated[case]["pt2"]
    assert got is not None, f"{case}: the .pt2 program returned instead of raising"
    mro, msg = got
    cls, part = CASES[case][2]
    assert mro[0] == cls, (case, mro, msg)
    assert part in msg, (case, msg)


@pytest.mark.parametrize("case", sorted(CASES))
def test_pt2_predictor_raises_the_torchscript_message(artifacts, isolated, case):
    pt2 = load_pt2_predictor(artifacts / "bem_predictor.pt2")
    x = eval(CASES[case][0])
    with pytest.raises(PredictorInputError) as info:
        pt2(x)
    assert isinstance(info.value, ValueError) and isinstance(info.value, BemlearnError)
    ts_message = isolated[case]["pt"][1]
    assert str(info.value) in ts_message, (str(info.value), ts_message)


def test_pt2_predictor_checks_every_method(artifacts):
    pt2 = load_pt2_predictor(artifacts / "bem_predictor.pt2")
    with pytest.raises(PredictorInputError, match=r"BEMPredictor.bem_mean: expected x of shape \(B, 3\)"):
        pt2.bem_mean(torch.zeros(0, 3, dtype=F64))
    with pytest.raises(PredictorInputError, match=r"BEMPredictor.predict_full: expected x of shape \(B, 5\)"):
        pt2.predict_full(torch.zeros(2, 3, dtype=F64))
    with pytest.raises(PredictorInputError, match=r"BEMPredictor.full_mean: x\[1, 4\] is inf"):
        pt2.full_mean(torch.tensor([[0.0] * 5, [0.0, 0, 0, 0, float("inf")]], dtype=F64))
    mean, std = pt2(torch.zeros(2, 3, dtype=F64))
    assert mean.shape == (2,) and std.shape == (2,)
