"""Only bemlearn's own predictor code is loaded (issue 29, items 1 and 2; bemlearn.export.archive_check).

TorchScript code runs when ``torch.jit.load`` compiles it (a ``__setstate__`` runs while the file
loads), and a ``.pt2`` graph names operators and holds strings torch evaluates.  Each tampered
archive below must be refused with a CheckpointError naming the file, before torch reads it.
"""

import json
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
import torch

from bemlearn.bench.predict_bench import synthetic_posterior
from bemlearn.errors import CheckpointError
from bemlearn.export import BEMPredictor, load_pt2_predictor, load_torchscript, save_pt2
from bemlearn.export.torchscript import save_torchscript

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    root = tmp_path_factory.mktemp("code")
    state, meta = synthetic_posterior(n_train=30, m=1, seed=4)
    predictor = BEMPredictor(state, meta)
    return {"pt": save_torchscript(predictor, root / "p.pt"), "pt2": save_pt2(predictor, root / "p.pt2")}


def _rewrite(src, dst, edit, add=None):
    """Copy the zip ``src`` to ``dst``; ``edit(name, bytes) -> bytes`` changes members; ``add`` adds some."""
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w") as zout:
        root = zin.namelist()[0].split("/")[0]
        for info in zin.infolist():
            zout.writestr(info, edit(info.filename, zin.read(info.filename)))
        for name, data in (add or {}).items():
            zout.writestr(f"{root}/{name}", data)
    return dst


def _edit_code(fn):
    return lambda name, data: fn(data.decode()).encode() if name.endswith(".py") else data


def _class_name(path) -> str:
    with zipfile.ZipFile(path) as z:
        code = next(n for n in z.namelist() if n.endswith(".py"))
    return "__torch__." + code.split("/code/__torch__/", 1)[1][:-3].replace("/", ".") + ".BEMPredictor"


def _evil_setstate(src, dst, victim: Path):
    """A predictor whose ``__setstate__`` maps ``victim`` shared and overwrites its first 8 bytes."""
    cls = _class_name(src)
    method = (
        f"  def __getstate__(self: {cls}) -> Dict[str, Tensor]:\n"
        "    _0 = annotate(Dict[str, Tensor], {})\n"
        "    return _0\n"
        f"  def __setstate__(self: {cls},\n    state: Dict[str, Tensor]) -> None:\n"
        f"    t = torch.from_file({str(victim)!r}, True, 8, dtype=0)\n"
        "    _1 = torch.fill_(t, 88)\n"
        "    if torch.eq(int(torch.sum(_1)), -1):\n"
        "      ops.prim.RaiseException(\"unreachable\", \"builtins.ValueError\")\n"
        "    else:\n"
        "      pass\n"
        "    return None\n"
    )
    return _rewrite(src, dst, _edit_code(lambda code: code.replace("  def forward(", method + "  def forward(", 1)))


def _simulate_config(tmp_path) -> Path:
    cfg = tmp_path / "sim.yaml"
    cfg.write_text("robot: furuta\nsimulate:\n  duration_s: 2.0\n  warmup_s: 0.5\n  bem_source: predictor\n")
    return cfg


def _cli(*argv, cwd):
    return subprocess.run([sys.executable, "-m", "bemlearn", *map(str, argv)], cwd=cwd, capture_output=True, text=True,
                          timeout=300, env={**__import__("os").environ, "PYTHONPATH": str(REPO)})


def test_a_setstate_that_writes_a_file_is_refused_before_it_runs(files, tmp_path):
    """Issue 29, item 1: `simulate --predictor evil.pt` overwrote the victim file while loading it."""
    victim = tmp_path / "victim.rc"
    victim.write_text("export PATH=/usr/bin\n")
    evil = _evil_setstate(files["pt"], tmp_path / "evil.pt", victim)
    res = _cli("simulate", _simulate_config(tmp_path), "--predictor", evil, "--out", tmp_path / "out", "--no-progress", cwd=tmp_path)
    assert victim.read_text() == "export PATH=/usr/bin\n"
    assert res.returncode == 2, res.stderr[-2000:]
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "evil.pt" in lines[0] and "refused" in lines[0] and "__setstate__" in lines[0], res.stderr
    assert not (tmp_path / "out").exists()


def test_a_foreign_torchscript_module_is_one_line(tmp_path):
    """Issue 29, item 2: a TorchScript module without bemlearn metadata ended in an AttributeError."""

    class Foreign(torch.nn.Module):
        def forward(self, x: torch.Tensor) -> torch.Tensor:
            return x.sum(1)

    foreign = tmp_path / "foreign.pt"
    torch.jit.save(torch.jit.script(Foreign()), str(foreign))
    with pytest.raises(CheckpointError, match=r"foreign.pt: refused: not a predictor written by this version"):
        load_torchscript(foreign)
    res = _cli("simulate", _simulate_config(tmp_path), "--predictor", foreign, "--out", tmp_path / "out", "--no-progress", cwd=tmp_path)
    assert res.returncode == 2, res.stderr[-2000:]
    assert len(res.stderr.strip().splitlines()) == 1 and "foreign.pt" in res.stderr and "internal error" not in res.stderr
    assert not (tmp_path / "out").exists()


def _changed_body(code: str) -> str:
    # the mean's matrix product replaced by a call that opens a file
    return code.replace("torch.addmv(", "torch.from_file(\"/etc/hostname\", False, 8, dtype=0).double().sum() + torch.addmv(", 1)


#: A protocol-2 pickle calling ``posix.system("true")``.
_SYSTEM_PICKLE = b"\x80\x02cposix\nsystem\nX\x04\x00\x00\x00true\x85R."

TAMPERED_TS = {
    "extra method": (_edit_code(lambda c: c.replace("  def forward(", "  def helper(self: __torch__.X, x: Tensor) -> Tensor:\n"
                                                                       "    return x\n  def forward(", 1)), None, r"method\(s\) \['helper'\]"),
    "changed method body": (_edit_code(_changed_body), None, r"the code of method '(forward|bem_mean|forward_latent|predict_full|full_mean|predict_full_latent)'"),
    "changed exception class": (_edit_code(lambda c: c.replace('"builtins.ValueError"', '"os.system"', 1)), None, r"the code of method"),
    "foreign module file": (lambda n, d: d, {"code/__torch__/evil.py": b"class Evil(Module):\n  __parameters__ = []\n"},
                            r"unexpected member 'code/__torch__/evil.py'"),
    "foreign pickle global": (lambda n, d: _SYSTEM_PICKLE if n.endswith("/data.pkl") else d, None, r"data.pkl names posix system"),
    "storage larger than its payload": (lambda n, d: d[:8] if n.endswith("/constants/1") else d, None,
                                        r"declares a DoubleStorage of \d+ elements in constants/1, which holds 8 bytes"),
    "extra member": (lambda n, d: d, {"extra/other.txt": b"x"}, r"unexpected member 'extra/other.txt'"),
}


@pytest.mark.parametrize("case", list(TAMPERED_TS))
def test_tampered_torchscript_archives_are_refused(files, tmp_path, case):
    edit, add, message = TAMPERED_TS[case]
    bad = _rewrite(files["pt"], tmp_path / "bad.pt", edit, add)
    with pytest.raises(CheckpointError, match=r"bad.pt: .*" + message):
        load_torchscript(bad)


def test_the_setstate_archive_is_refused_in_process_and_the_victim_kept(files, tmp_path):
    from bemlearn.control.bem_sources import PredictorBEM

    victim = tmp_path / "victim"
    victim.write_bytes(b"0123456789")
    evil = _evil_setstate(files["pt"], tmp_path / "evil.pt", victim)
    with pytest.raises(CheckpointError, match=r"evil.pt: refused: .*\['__getstate__', '__setstate__'\]"):
        PredictorBEM(evil)
    assert victim.read_bytes() == b"0123456789"


def _edit_program(name: str, fn):
    def edit(member: str, data: bytes) -> bytes:
        if member.endswith(f"/models/{name}.json"):
            doc = json.loads(data)
            fn(doc)
            return json.dumps(doc).encode()
        return data
    return edit


def _from_file_node(doc):
    node = next(n for n in doc["graph_module"]["graph"]["nodes"] if n["target"].endswith("aten.addmv.default"))
    node["target"] = "torch.ops.aten.from_file.default"


def _eval_symbol(doc):
    doc["range_constraints"] = {"__import__('os').system('true')": {"min_val": 1, "max_val": None}}


def _guard(doc):
    doc["guards_code"] = ["__import__('os').system('true')"]


TAMPERED_PT2 = {
    "operator that opens a file": (_edit_program("bem_mean", _from_file_node), None, r"models/bem_mean.json calls 'torch.ops.aten.from_file.default'"),
    "evaluated symbolic size": (_edit_program("model", _eval_symbol), None, r"models/model.json holds the symbolic size"),
    "guard code": (_edit_program("model", _guard), None, r"models/model.json carries custom objects or guard code"),
    "extra program": (lambda n, d: d, {"models/evil.json": b"{}"}, r"unexpected program models/evil.json"),
}


@pytest.mark.parametrize("case", list(TAMPERED_PT2))
def test_tampered_pt2_archives_are_refused(files, tmp_path, case):
    edit, add, message = TAMPERED_PT2[case]
    bad = _rewrite(files["pt2"], tmp_path / "bad.pt2", edit, add)
    with pytest.raises(CheckpointError, match=r"bad.pt2: .*" + message):
        load_pt2_predictor(bad)


def test_untampered_archives_of_every_structure_load(files, tmp_path):
    """The allow-list is the exporter's own code: a predictor with any combination of the structural
    flags (raw / centred, triangular / factored / signed variance, band) loads and predicts as exported."""
    from bemlearn.export.archive_check import _flag_combinations, _with_flags, reference_predictor

    base = reference_predictor(m=2, n_support=7)
    x = torch.linspace(-1, 1, 18, dtype=torch.float64).reshape(3, 6)
    for i, flags in enumerate(_flag_combinations()):
        p = _with_flags(base, flags, flags)
        loaded = load_torchscript(save_torchscript(p, tmp_path / f"p{i}.pt"))
        assert torch.equal(loaded.bem_mean(x), p.bem_mean(x))


@pytest.mark.parametrize("out", ["--out", None])
def test_a_failing_simulate_removes_the_folder_it_created(files, tmp_path, out):
    """Issue 29, item 10: a simulate that failed (here: a predictor for another robot, found once the loop's
    robot is loaded) left the folder it created, with an empty tb/."""
    argv = ["simulate", _simulate_config(tmp_path), "--predictor", files["pt"], "--no-progress"]
    argv += ["--out", tmp_path / "out"] if out else []
    res = _cli(*argv, cwd=tmp_path)
    assert res.returncode == 2, res.stderr[-2000:]
    assert "predictor is for robot 'synthetic'" in res.stderr
    assert not (tmp_path / "out").exists() and not (tmp_path / "runs").exists()
