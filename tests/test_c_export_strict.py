"""The C export of a real trained run builds clean under ``-std=c99 -Wall -Wextra -pedantic -Werror``
and carries no absolute path of the machine that exported it (issue 22, docs/c-export.md).

Before issue 22 the header's metadata JSON was one string literal of ~5.8 k characters (C99
compilers need only support 4095: ``-Woverlength-strings``) and held the absolute paths of the
data file and the MJCF.
"""

import json
import os
import re
import subprocess
from pathlib import Path

import pytest
import yaml

from bemlearn.cli.main import main
from bemlearn.export.c_build import CPredictorLibrary, compile_shared, find_cc

pytestmark = pytest.mark.skipif(find_cc() is None, reason="no C compiler (cc, gcc, clang or $CC) on PATH")

ROOT = Path(__file__).resolve().parents[1]
PEDANTIC = ("-std=c99", "-Wall", "-Wextra", "-pedantic", "-Werror")


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """A run trained by ``bemlearn train`` on a data file given by its absolute path, exported with --format c."""
    root = tmp_path_factory.mktemp("cstrict")
    cfg = yaml.safe_load((ROOT / "configs/furuta.yaml").read_text())
    cfg["dataset"]["n_points"] = 120
    cfg["train"]["max_iter"] = 10
    (root / "c.yaml").write_text(yaml.safe_dump(cfg))
    data = (ROOT / "data/furuta_excitation.npz").resolve()
    assert main(["train", str(root / "c.yaml"), "--data", str(data), "--out", str(root / "run"), "--no-progress"]) == 0
    assert main(["export", str(root / "run"), "--format", "c", "--out", str(root / "c")]) == 0
    return root, data


def test_a_real_export_compiles_under_pedantic_c99(exported, tmp_path):
    root, _ = exported
    header = (root / "c" / "bem_predictor.h").read_text()
    meta_len = len(header[header.index("bem_metadata_json[] = {"):header.index("};", header.index("bem_metadata_json[] = {"))].split(","))
    assert meta_len > 4095  # the metadata is longer than a C99 string literal may be
    cc = find_cc()
    res = subprocess.run([cc, *PEDANTIC, "-O2", "-c", str(root / "c" / "bem_predictor.c"), "-o", str(tmp_path / "p.o")],
                         capture_output=True, text=True)
    assert res.returncode == 0 and not res.stderr, res.stderr[-3000:]
    lib = CPredictorLibrary(compile_shared([root / "c" / "bem_predictor.c"], tmp_path / "libbem.so", flags=(*PEDANTIC, "-O2")))
    doc = json.loads(lib.metadata_json)  # the character array is the NUL-terminated JSON
    assert doc["c_export"]["prefix"] == "bem" and doc["robot"] == "furuta"


def test_the_export_carries_no_absolute_path(exported):
    root, data = exported
    text = (root / "c" / "bem_predictor.h").read_text() + (root / "c" / "bem_predictor.c").read_text()
    lib_doc = json.loads(bytes(int(c) for c in re.search(r"bem_metadata_json\[\] = \{([^}]*)\}", text).group(1).replace("\n", "").split(",")[:-1]).decode())
    machine = {str(data), str(data.parent), str(root), str(ROOT), str(Path.home()), os.getcwd(), "/tmp", "/home", "/root", "/work"}
    for where, blob in (("source", text), ("metadata", json.dumps(lib_doc))):
        found = [p for p in machine if p and p != "/" and p in blob]
        assert not found, f"the {where} names {found}"
    assert lib_doc["extra"]["data_file"] == data.name  # reduced to the file name, not dropped
    assert lib_doc["extra"]["robot_ref"]["mjcf"] == "furuta.xml"
