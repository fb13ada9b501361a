"""scripts/diff_metrics.py names every key two metrics.json files disagree on, at the printed digit and exactly."""

import json
from pathlib import Path

from tests.file_module import load_file_module

SCRIPT = Path(__file__).resolve().parent.parent / "scripts" / "diff_metrics.py"


def _module():
    return load_file_module(SCRIPT)


def _write(folder: Path, doc: dict) -> Path:
    folder.mkdir()
    path = folder / "metrics.json"
    path.write_text(json.dumps(doc))
    return path


def test_each_kind_of_difference_is_named(tmp_path, capsys):
    mod = _module()
    a = {"fit": {"seconds": 2.5, "rmse": 0.0123456, "n": 500}, "loop": {"u_max": 1.25, "fell": False},
         "data": {"file": str(tmp_path / "a" / "data.npz")}, "list": [1.0, 2.0], "only_a": 1}
    b = {"fit": {"seconds": 9.0, "rmse": 0.0123457, "n": 500}, "loop": {"u_max": 1.251, "fell": True},
         "data": {"file": str(tmp_path / "b" / "data.npz")}, "list": [1.0, 2.0, 3.0]}
    status = mod.main([str(_write(tmp_path / "a", a)), str(_write(tmp_path / "b", b))])
    out = capsys.readouterr().out
    assert status == 1
    found = {line.split()[0]: line.split()[-1] for line in out.splitlines() if line.startswith("  ")}
    assert found == {"fit.rmse": "[exact]",            # 0.01235 either way at 4 significant digits
                     "loop.u_max": "[printed]",         # 1.25 vs 1.251
                     "loop.fell": "[value]", "list[2]": "B]", "only_a": "A]", "fit.seconds": "[printed]"}
    assert "data.file" not in found                     # each file's own run folder is replaced by <run>
    assert "4 key(s) differ" not in out and "5 key(s) differ:" in out and "1 key(s) wall-clock measurements" in out


def test_the_same_metrics_exit_0_and_ignored_keys_are_skipped(tmp_path, capsys):
    mod = _module()
    doc = {"robot": {"mjcf": "/x/a.xml"}, "closed_loop": {"model": {"tracking_rmse": 0.01, "tick_us": {"physics": 50.0}}}}
    other = {"robot": {"mjcf": "/y/a.xml"}, "closed_loop": {"model": {"tracking_rmse": 0.01, "tick_us": {"physics": 80.0}}}}
    a, b = _write(tmp_path / "a", doc), _write(tmp_path / "b", other)
    assert mod.main([str(a), str(b), "--ignore", r"^robot\.mjcf$"]) == 0
    assert mod.main([str(a), str(b)]) == 1
    assert mod.main([str(a), str(tmp_path / "missing.json")]) == 2
    assert "cannot read" in capsys.readouterr().err
