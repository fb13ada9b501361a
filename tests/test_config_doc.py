"""docs/config.md documents every key of a pipeline config and matches the code."""

import dataclasses
import typing
from pathlib import Path

from bemlearn.pipeline.config import PipelineConfig
from bemlearn.pipeline.config_doc import attribute_docs, config_markdown

DOC = Path(__file__).resolve().parents[1] / "docs" / "config.md"


def _keys(cls, prefix=""):
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        tp = hints[f.name]
        if dataclasses.is_dataclass(tp):
            yield from _keys(tp, f"{prefix}{f.name}.")
        else:
            yield f"{prefix}{f.name}", cls, f.name


def test_every_key_has_a_description():
    missing = [key for key, cls, name in _keys(PipelineConfig) if not attribute_docs(cls).get(name)]
    assert not missing, f"config keys without a description in their dataclass docstring: {missing}"


def test_docs_config_md_is_generated_from_the_code():
    text = config_markdown()
    for key, _, _ in _keys(PipelineConfig):
        assert f"| `{key}` |" in text
    assert DOC.read_text() == text, "docs/config.md is stale: run `python -m bemlearn.pipeline.config_doc > docs/config.md`"


def test_attribute_docs_parses_shared_and_continued_entries():
    @dataclasses.dataclass
    class C:
        """Summary.

        Attributes:
            a, b: shared text
                continued here.
            c: own text.
        """

        a: int = 0
        b: int = 0
        c: int = 0

    assert attribute_docs(C) == {"a": "shared text continued here.", "b": "shared text continued here.", "c": "own text."}
