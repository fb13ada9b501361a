"""Every reader of a file a user may have received refuses pickled code (issue 22, bemlearn.safe_load).

Each tampered file carries a pickle whose ``__reduce__`` would create a folder (a harmless
stand-in for any call): the reader must end in a named error and the folder must not exist.
"""

import io
import json
import os
import pickle
import zipfile

import numpy as np
import pytest
import torch

from bemlearn.bench.predict_bench import synthetic_posterior
from bemlearn.errors import CheckpointError, TrajectoryFormatError
from bemlearn.export import BEMPredictor, load_checkpoint, load_pt2_predictor, load_torchscript, save_pt2, write_checkpoint
from bemlearn.export.torchscript import save_torchscript


class _Reduce:
    """Unpickling this calls ``os.mkdir(path)``."""

    def __init__(self, path):
        self.path = str(path)

    def __reduce__(self):
        return (os.mkdir, (self.path,))


def _torch_payload(obj) -> bytes:
    buf = io.BytesIO()
    torch.save(obj, buf)
    return buf.getvalue()


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    root = tmp_path_factory.mktemp("safe")
    state, meta = synthetic_posterior(n_train=40, m=1, seed=3)
    predictor = BEMPredictor(state, meta)
    write_checkpoint(root / "run", model_state={"w": torch.ones(2)}, predictor_state=state, metadata=meta)
    return {"pt2": save_pt2(predictor, root / "p.pt2"), "pt": save_torchscript(predictor, root / "p.pt"),
            "checkpoint": root / "run" / "checkpoint.pt"}


def _rewrite_zip(src, dst, replace: dict, add: dict | None = None):
    """Copy the zip ``src`` to ``dst``, members whose name ends with a key of ``replace`` replaced."""
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w") as zout:
        root = zin.namelist()[0].split("/")[0]
        for info in zin.infolist():
            data = zin.read(info.filename)
            for suffix, new in replace.items():
                if info.filename.endswith(suffix):
                    data = new(data) if callable(new) else new
            zout.writestr(info, data)
        for name, data in (add or {}).items():
            zout.writestr(f"{root}/{name}", data)
    return dst


def test_pt2_whose_sample_inputs_carry_a_reduce_is_refused(files, tmp_path):
    marker = tmp_path / "ran"
    bad = _rewrite_zip(files["pt2"], tmp_path / "bad.pt2", {"data/sample_inputs/bem_mean.pt": _torch_payload(_Reduce(marker))})
    with pytest.raises(CheckpointError, match=r"bad.pt2: data/sample_inputs/bem_mean.pt: refused: .*would run code; it names posix.mkdir"):
        load_pt2_predictor(bad)
    assert not marker.exists()


def test_pt2_with_a_pickled_weight_is_refused(files, tmp_path):
    marker = tmp_path / "ran"

    def pickled(config: bytes) -> bytes:
        doc = json.loads(config)
        first = next(iter(doc["config"].values()))
        first["use_pickle"] = True
        return json.dumps(doc).encode()

    bad = _rewrite_zip(files["pt2"], tmp_path / "bad.pt2", {"data/weights/model_weights_config.json": pickled,
                                                            "data/weights/weight_0": _torch_payload(_Reduce(marker))})
    with pytest.raises(CheckpointError, match=r"model_weights_config.json loads .* as a pickled object"):
        load_pt2_predictor(bad)
    assert not marker.exists()


def test_pt2_with_an_opaque_object_constant_is_refused(files, tmp_path):
    marker = tmp_path / "ran"
    config = {"config": {"evil": {"path_name": "opaque_obj_0", "is_param": False, "use_pickle": True, "tensor_meta": None}}}
    bad = _rewrite_zip(files["pt2"], tmp_path / "bad.pt2", {"data/constants/model_constants_config.json": json.dumps(config).encode()},
                       add={"data/constants/opaque_obj_0": pickle.dumps(_Reduce(marker))})
    with pytest.raises(CheckpointError, match="refused"):
        load_pt2_predictor(bad)
    assert not marker.exists()


def test_pt2_with_a_native_library_is_refused(files, tmp_path):
    bad = _rewrite_zip(files["pt2"], tmp_path / "bad.pt2", {}, add={"data/aotinductor/model/model.so": b"\x7fELF"})
    with pytest.raises(CheckpointError, match=r"refused: unexpected member 'data/aotinductor/model/model.so'"):
        load_pt2_predictor(bad)


def test_the_checked_pt2_still_loads_and_predicts(files):
    pt2 = load_pt2_predictor(files["pt2"])
    scripted = load_torchscript(files["pt"])
    x = torch.zeros(2, 3, dtype=torch.float64)
    assert torch.equal(pt2.bem_mean(x), scripted.bem_mean(x))


def test_torchscript_whose_pickle_carries_a_reduce_is_refused(files, tmp_path):
    from bemlearn.control.bem_sources import PredictorBEM

    marker = tmp_path / "ran"
    bad = _rewrite_zip(files["pt"], tmp_path / "bad.pt", {"/data.pkl": pickle.dumps(_Reduce(marker), protocol=2)})
    # refused by the archive check before torch reads it (bemlearn.export.archive_check) ...
    with pytest.raises(CheckpointError, match="bad.pt: refused: .*data.pkl names posix mkdir"):
        load_torchscript(bad)
    with pytest.raises(CheckpointError, match="bad.pt: refused: .*data.pkl names posix mkdir"):
        PredictorBEM(bad)
    # ... and by torch's C++ unpickler itself
    from bemlearn.safe_load import load_script_module

    with pytest.raises(CheckpointError, match="bad.pt: not a TorchScript file"):
        load_script_module(bad)
    assert not marker.exists()


def test_checkpoint_whose_pickle_carries_a_reduce_is_refused(files, tmp_path):
    marker = tmp_path / "ran"
    data = torch.load(files["checkpoint"], weights_only=True)
    data["extra_object"] = _Reduce(marker)
    bad = tmp_path / "checkpoint.pt"
    torch.save(data, bad)
    with pytest.raises(CheckpointError, match=r"checkpoint.pt: refused: .*would run code; it names posix.mkdir"):
        load_checkpoint(bad)
    assert not marker.exists()


def test_npz_with_an_object_array_is_refused(tmp_path):
    from bemlearn.data import read_trajectory

    marker = tmp_path / "ran"
    bad = tmp_path / "bad.npz"
    np.savez(bad, meta=np.array("{}"), t=np.array([_Reduce(marker)], dtype=object), trial=np.zeros(1), q=np.zeros((1, 2)), u=np.zeros((1, 1)))
    with pytest.raises(TrajectoryFormatError, match="bad.npz: not a readable NPZ file"):
        read_trajectory(bad)
    assert not marker.exists()
