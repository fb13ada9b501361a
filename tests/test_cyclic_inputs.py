"""A cyclic actuated coordinate without a joint range leaves the GP inputs (``dataset.cyclic``): derived from
the model, fitted as a constant column and frozen with ℓ = LEFT_OUT_LENGTHSCALE, so that the BEM predictor gives
the same μ and σ at any value of that position — eager and exported alike — while the input layout stays."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from bemlearn.config import ConfigError
from bemlearn.data.normalization import Normalization
from bemlearn.fitting.gp_config import GPConfig
from bemlearn.models.kernels import LEFT_OUT_LENGTHSCALE
from bemlearn.pipeline.gp_stage import CheckpointProvenance, fit_bem_gp
from bemlearn.robots import load
from bemlearn.robots.cyclic import unbounded_cyclic

ROBOTS = Path(__file__).parent / "robots"
NAMES = ("qdd_wheel", "qd_wheel", "q_wheel", "qdd_pole", "qd_pole")
UNITS = dict(zip(NAMES, ("rad/s^2", "rad/s", "rad", "rad/s^2", "rad/s")))


@pytest.mark.parametrize(("robot", "expected"), [
    (str(ROBOTS / "reaction_wheel.xml"), ("wheel",)),   # cyclic, no range
    ("furuta", ("theta",)),                              # the arm turns round: cyclic, no range
    (str(ROBOTS / "cartpole.xml"), ()),                  # cyclic, but the rail bounds it
    (str(ROBOTS / "pendubot.xml"), ()),                  # gravity depends on the shoulder
])
def test_the_unbounded_cyclic_coordinates_of_the_zoo(robot, expected):
    assert unbounded_cyclic(load(robot)) == expected


def _data(seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """q_u = 0.1 sin(q̈_w / 4) + 0.05 sin(q̇_w) − 0.05 tanh(q̈_u / 2) + noise (nothing of q_w, which spans ±3 rad)."""
    g = torch.Generator().manual_seed(seed)
    x = torch.empty(150, 5, dtype=torch.float64)
    x[:, 0] = 4.0 * torch.randn(150, generator=g, dtype=torch.float64)
    x[:, 1] = torch.randn(150, generator=g, dtype=torch.float64)
    x[:, 2] = 6.0 * torch.rand(150, generator=g, dtype=torch.float64) - 3.0
    x[:, 3] = 2.0 * torch.randn(150, generator=g, dtype=torch.float64)
    x[:, 4] = 0.5 * torch.randn(150, generator=g, dtype=torch.float64)
    y = (0.1 * torch.sin(x[:, 0] / 4) + 0.05 * torch.sin(x[:, 1]) - 0.05 * torch.tanh(x[:, 3] / 2)
         + 3e-3 * torch.randn(150, generator=g, dtype=torch.float64))
    return x, y


def _fit(tmp_path, left_out):
    x, y = _data()
    return fit_bem_gp(
        x, y, tmp_path, normalization=Normalization.fit(x, y, names=NAMES), input_names=NAMES, units=UNITS,
        config=GPConfig(kind="exact", max_iter=60),
        provenance=CheckpointProvenance(robot={"name": "synthetic", "mjcf": None}, joint_names=("wheel", "pole"),
                                        unactuated_name="pole", data_sha256="0" * 64),
        progress=False, left_out=left_out,
    )


def test_a_left_out_position_changes_neither_mean_nor_std_anywhere_eager_and_exported(tmp_path):
    from bemlearn.export import BEMPredictor, PredictorMetadata, save_torchscript
    from bemlearn.export.torchscript import load_torchscript

    stage = _fit(tmp_path / "left", ("q_wheel",))
    st = stage.state
    assert float(st.lengthscale[2]) == LEFT_OUT_LENGTHSCALE and stage.lengthscale_physical["q_wheel"] is None
    assert torch.all(st.Z[:, 2] == 0.0)
    base = torch.tensor([[3.0, 0.4, 0.0, 0.0, 0.0], [-5.0, -1.0, 0.0, 0.0, 0.0]], dtype=torch.float64)
    far = base.clone()
    far[:, 2] = torch.tensor([300.0, -5000.0])           # hundreds of turns beyond the data's ±3 rad
    (m0, s0), (m1, s1) = st.predict_reference(base), st.predict_reference(far)
    torch.testing.assert_close(m1, m0, rtol=0, atol=1e-12)
    torch.testing.assert_close(s1, s0, rtol=0, atol=1e-12)
    # and the map itself is learned: 0.1 sin(q̈_w / 4) + 0.05 sin(q̇_w) at the BEM queries
    truth = 0.1 * torch.sin(base[:, 0] / 4) + 0.05 * torch.sin(base[:, 1])
    assert float((m0 - truth).abs().max()) < 0.01
    meta = PredictorMetadata(
        robot="synthetic", joint_names=("wheel", "pole"), actuated_names=("wheel",), unactuated_name="pole", m=1,
        input_names=NAMES, units=UNITS, n_train=st.n_train, n_inducing=None, hyperparameters={},
        bemlearn_version="test", data_sha256="0" * 64,
    )
    exported = load_torchscript(save_torchscript(BEMPredictor(st, meta), tmp_path / "p.pt"))
    e0, e1 = exported(base[:, :3]), exported(far[:, :3])
    torch.testing.assert_close(e1[0], e0[0], rtol=0, atol=1e-12)
    torch.testing.assert_close(e0[0], m0, rtol=0, atol=1e-12)
    # kept as an input (learned ℓ ≈ 1100 rad), the same data move the BEM by 0.011 rad at 300 rad and 0.14 rad at
    # −5000 rad (toward the prior): the reason to leave it out
    kept = _fit(tmp_path / "kept", ()).state
    mk0, _ = kept.predict_reference(base)
    mk1, _ = kept.predict_reference(far)
    assert float((mk1 - mk0).abs().max()) > 0.05


def test_a_left_out_name_that_is_not_a_column_or_joint_is_refused(tmp_path):
    from bemlearn.errors import ArgumentError
    from bemlearn.pipeline.train import _left_out_columns

    with pytest.raises(ArgumentError, match=r"left_out: \['q_pole'\] are not input columns"):
        _fit(tmp_path, ("q_pole",))
    assert _left_out_columns(("wheel",), ("wheel",)) == ("q_wheel",) and _left_out_columns(None, ("wheel",)) == ()
    with pytest.raises(ConfigError, match=r"dataset\.cyclic: \['pole'\] are not actuated joints of the data; expected "
                                          r"names among \['wheel'\]"):
        _left_out_columns(("pole",), ("wheel",))
