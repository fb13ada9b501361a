"""The .pt2 predictor evaluates large batches in row blocks (issue 29, item 7): the same numbers,
the memory of one block (`bemlearn bench hostile` measures it on 10⁶ rows)."""

import torch

from bemlearn.bench.predict_bench import synthetic_posterior
from bemlearn.export import BEMPredictor, load_pt2_predictor, save_pt2


def test_chunked_evaluation_equals_one_block(tmp_path):
    state, meta = synthetic_posterior(n_train=60, m=1, seed=7)
    p2 = load_pt2_predictor(save_pt2(BEMPredictor(state, meta), tmp_path / "p.pt2"))
    x = torch.randn(2500, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(1)) * torch.tensor([20.0, 3.0, 1.0], dtype=torch.float64)
    xf = torch.cat([x, torch.zeros(2500, 2, dtype=torch.float64)], 1)
    whole = {"forward": p2.forward(x), "bem_mean": p2.bem_mean(x), "predict_full": p2.predict_full(xf)}
    assert p2.chunk == 1024
    p2.chunk = 700   # 2500 rows: blocks of 700, 700, 700, 400
    chunked = {"forward": p2.forward(x), "bem_mean": p2.bem_mean(x), "predict_full": p2.predict_full(xf)}
    p2.chunk = 10**9
    single = {"forward": p2.forward(x), "bem_mean": p2.bem_mean(x), "predict_full": p2.predict_full(xf)}
    for name in whole:
        as_tuple = [v if isinstance(v, tuple) else (v,) for v in (whole[name], chunked[name], single[name])]
        for a, b, c in zip(*as_tuple):
            assert a.shape == (2500,)
            torch.testing.assert_close(a, c, rtol=0, atol=1e-15)
            torch.testing.assert_close(b, c, rtol=0, atol=1e-15)
