"""Checkpoint write/read round trip and the errors for malformed checkpoints."""

import dataclasses

import numpy as np
import pytest
import torch

from bemlearn.bench.predict_bench import synthetic_posterior
from bemlearn.export import CHECKPOINT_FORMAT, PredictorMetadata, load_checkpoint, write_checkpoint

F64 = torch.float64


class _Opaque:
    """Not loadable with weights_only=True."""


@pytest.fixture(scope="module")
def posterior():
    return synthetic_posterior(n_train=40, m=1, seed=2)


@pytest.fixture
def run_dir(tmp_path, posterior):
    state, meta = posterior
    write_checkpoint(tmp_path / "run", model_state={"w": torch.ones(3)}, predictor_state=state, metadata=meta)
    return tmp_path / "run"


def _rewrite(run_dir, edit):
    path = run_dir / "checkpoint.pt"
    data = torch.load(path, weights_only=True)
    edit(data)
    torch.save(data, path)
    return path


def test_round_trip(run_dir, posterior):
    state, meta = posterior
    ckpt = load_checkpoint(run_dir)
    assert ckpt.path == run_dir / "checkpoint.pt" and ckpt.kind == "exact"
    assert torch.equal(ckpt.model_state["w"], torch.ones(3))
    for name, tensor in state.tensors().items():
        assert torch.equal(getattr(ckpt.predictor_state, name), tensor), name
    assert ckpt.predictor_state.input_names == state.input_names
    assert ckpt.metadata == meta
    assert load_checkpoint(run_dir / "checkpoint.pt").metadata == meta
    raw = torch.load(run_dir / "checkpoint.pt", weights_only=True)
    assert raw["format"] == CHECKPOINT_FORMAT and set(raw) == {"format", "kind", "model_state", "predictor_state", "metadata", "content_sha256"}


def test_metadata_extras_and_unit_list_are_kept(tmp_path, posterior):
    state, meta = posterior
    data = meta.to_dict() | {
        "config": {"seed": 3},
        "extra": {"report": {"n": np.int64(4), "rmse": np.float64(0.5)}},
        "units": ["rad/s^2", "rad/s", "rad", "rad/s^2", "rad/s"],
    }
    path = write_checkpoint(tmp_path / "ckpt.pt", model_state={}, predictor_state=state, metadata=data)
    loaded = load_checkpoint(path).metadata
    assert loaded.extra == {"config": {"seed": 3}, "report": {"n": 4, "rmse": 0.5}}
    assert loaded.units == dict(zip(meta.input_names, data["units"]))
    assert load_checkpoint(path).artifact_metadata()["extra"] == {"config": {"seed": 3}, "report": {"n": 4, "rmse": 0.5}}
    with pytest.raises(ValueError, match=r"key\(s\) \['config'\] given both"):
        PredictorMetadata.from_dict(data | {"extra": {"config": 1}})


def test_missing_paths(tmp_path):
    with pytest.raises(FileNotFoundError, match="nowhere: no such checkpoint file or run directory"):
        load_checkpoint(tmp_path / "nowhere")
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileNotFoundError, match=r"empty/checkpoint.pt: no checkpoint in run directory"):
        load_checkpoint(tmp_path / "empty")


def test_not_a_checkpoint(tmp_path):
    junk = tmp_path / "junk.pt"
    junk.write_text("hello")
    with pytest.raises(ValueError, match="junk.pt: cannot be read as a bemlearn checkpoint"):
        load_checkpoint(junk)
    unsafe = tmp_path / "unsafe.pt"
    torch.save({"format": CHECKPOINT_FORMAT, "obj": _Opaque()}, unsafe)
    with pytest.raises(ValueError, match="unsafe.pt: refused: the file holds pickled objects other than tensors"):
        load_checkpoint(unsafe)
    listy = tmp_path / "list.pt"
    torch.save([1, 2], listy)
    with pytest.raises(ValueError, match="list.pt: expected a dict"):
        load_checkpoint(listy)


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda d: d.pop("metadata"), r"missing key\(s\) \['metadata'\]"),
        (lambda d: d.update(format="v0"), r"format is 'v0', expected 'bemlearn-checkpoint-v1'"),
        (lambda d: d.update(kind="gpdm"), r"kind is 'gpdm', expected one of"),
        (lambda d: d.update(kind="sgpr"), r"predictor_state.kind: 'exact' differs from the checkpoint's kind 'sgpr'"),
        (lambda d: d["predictor_state"].pop("alpha"), r"predictor_state: missing key\(s\) \['alpha'\]"),
        (lambda d: d["predictor_state"].update(extra=1), r"predictor_state: unknown key\(s\) \['extra'\]"),
        (lambda d: d["predictor_state"].update(alpha=d["predictor_state"]["alpha"].float()), r"predictor_state.alpha: expected float64"),
        (lambda d: d["predictor_state"]["Z"].__setitem__((0, 0), float("nan")), r"predictor_state.Z: has non-finite values"),
        (lambda d: d["predictor_state"].update(alpha=torch.zeros(3, dtype=F64)), r"PredictorState.alpha: expected shape \(40,\)"),
        (lambda d: d["predictor_state"].update(lengthscale=-d["predictor_state"]["lengthscale"]), r"predictor_state.lengthscale: expected positive"),
        (lambda d: d["metadata"].pop("robot"), r"metadata: missing required key 'robot'"),
        (lambda d: d["metadata"].update(m="one"), r"metadata.m: expected an integer"),
        (lambda d: d["metadata"].update(m=2), r"actuated_names: expected m = 2 names"),
        (lambda d: d["metadata"].update(n_inducing=40), r"n_inducing: expected null for an exact GP"),
        (lambda d: d["metadata"].update(n_train=39), r"n_train = 39 but PredictorState.n_train = 40"),
        (lambda d: d["metadata"].update(data_sha256="abc"), r"data_sha256: expected 64 lowercase hex digits"),
        (lambda d: d["metadata"]["units"].pop("q_a0"), r"units: no unit for input column\(s\) \['q_a0'\]"),
        (lambda d: d["metadata"].update(input_names=list("abcde"), units=dict.fromkeys("abcde", "rad")), r"PredictorState.input_names .* differ from metadata.input_names"),
    ],
)
def test_malformed_checkpoint_names_file_and_key(run_dir, edit, message):
    path = _rewrite(run_dir, edit)
    with pytest.raises(ValueError, match=message) as info:
        load_checkpoint(run_dir)
    assert str(path) in str(info.value)


def test_write_rejects_inconsistent_input(tmp_path, posterior):
    state, meta = posterior
    with pytest.raises(ValueError, match="n_inducing: expected 40"):
        write_checkpoint(
            tmp_path, model_state={}, predictor_state=dataclasses.replace(state, kind="sgpr"), metadata=meta
        )
    with pytest.raises(TypeError, match=r"hyperparameters.f: cannot store a object"):
        PredictorMetadata(**{**meta.__dict__, "hyperparameters": {"f": object()}})
    assert not (tmp_path / "checkpoint.pt").exists()
