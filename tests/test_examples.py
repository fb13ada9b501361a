"""The examples shipped inside the package: listed, found by name from any folder, copied without overwriting."""

from __future__ import annotations

from pathlib import Path

import pytest

from bemlearn.cli.main import main
from bemlearn.errors import MissingFileError, OutputExistsError
from bemlearn.examples import EXAMPLES_DIR, config_argument, copy_examples, example_path, examples

ROOT = Path(__file__).resolve().parents[1]


def test_the_package_holds_the_repository_files():
    """In a checkout the package's examples are the repository's own files (one copy, never two)."""
    for rel in ("configs/furuta.yaml", "configs/sweeps/example.yaml", "tests/robots/cartpole.xml", "data/furuta_excitation.npz",
                "data/human_gait/human_gait_right.csv"):
        assert (EXAMPLES_DIR / rel).resolve() == (ROOT / rel).resolve(), rel
    assert {"furuta", "biped", "sweeps/example", "sweeps/robots"} <= set(examples())
    assert examples()["sweeps/example"].kind == "sweep" and examples()["furuta"].kind == "config"


def test_a_config_argument_names_an_example_from_any_folder(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert config_argument("furuta") == EXAMPLES_DIR / "configs" / "furuta.yaml"
    assert config_argument("configs/furuta.yaml") == EXAMPLES_DIR / "configs" / "furuta.yaml"
    assert config_argument("sweeps/example") == EXAMPLES_DIR / "configs" / "sweeps" / "example.yaml"
    assert main(["config", "show", "furuta"]) == 0  # the example, from an empty folder
    (tmp_path / "furuta").write_text("robot: my.xml\n")  # a file of the user's wins over an example of that name
    assert config_argument("furuta") == Path("furuta")
    assert config_argument("nope.yaml") == Path("nope.yaml")
    assert main(["examples"]) == 0
    out = capsys.readouterr().out
    assert "furuta " in out and "sweeps/example" in out


def test_example_path_names_only_shipped_files():
    assert example_path("tests/robots/cartpole.xml").is_file()
    with pytest.raises(MissingFileError, match="not a shipped example file"):
        example_path("bemlearn/__init__.py")
    with pytest.raises(MissingFileError):
        example_path("tests/robots/none.xml")


def test_copy_keeps_existing_files_unless_forced(tmp_path):
    written = copy_examples(tmp_path / "ex")
    assert (tmp_path / "ex" / "configs" / "sweeps" / "example.yaml").is_file()
    assert len(written) >= 14 and all(p.is_file() for p in written)
    mine = tmp_path / "ex" / "configs" / "furuta.yaml"
    mine.write_text("robot: furuta\n# edited\n")
    with pytest.raises(OutputExistsError, match="use --force"):
        copy_examples(tmp_path / "ex")
    assert mine.read_text().endswith("# edited\n")
    copy_examples(tmp_path / "ex", force=True)
    assert mine.read_text() == (ROOT / "configs" / "furuta.yaml").read_text()
