"""The README's API tour runs as written, its commands parse and pass their option checks, the
files and pages it names exist, and its quickstart matches .ci/run."""

import re
import shlex
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_readme_api_tour_runs(monkeypatch, capsys):
    text = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    assert blocks, "README has no python block"
    monkeypatch.chdir(ROOT)
    for code in blocks:
        exec(compile(code, "README.md", "exec"), {})
    out = capsys.readouterr().out
    assert "tensor" in out


def test_ci_runs_exactly_the_readme_test_command():
    text = (ROOT / "README.md").read_text()
    cmds = re.findall(r"```bash\n(pip install torch==2\.13\.0 && pip install -e \"\.\[test\]\" && python -m pytest)\n```", text)
    assert cmds, "README quickstart test command not found"
    ci = (ROOT / ".ci" / "run").read_text().strip().splitlines()
    assert ci[-1] == cmds[0]


def _readme_commands(text: str) -> list[str]:
    """Every ``bemlearn …`` command line the README shows (inline code and bash blocks); a bare
    ``bemlearn NAME`` is the name of a command, not a command line."""
    cmds = [s for s in re.findall(r"`([^`\n]+)`", text) if s.startswith("bemlearn ")]
    for block in re.findall(r"```bash\n(.*?)```", text, flags=re.S):
        for line in block.splitlines():
            cmds += [c.strip() for c in line.split("#")[0].split("&&") if c.strip().startswith("bemlearn ")]
    return sorted({c for c in cmds if len(shlex.split(c)) > 2})


def test_readme_commands_parse_and_pass_their_option_checks():
    from bemlearn.cli.main import build_parser

    cmds = _readme_commands((ROOT / "README.md").read_text())
    assert any(c.startswith("bemlearn export") for c in cmds) and len(cmds) >= 8, cmds
    parser = build_parser()
    for cmd in cmds:
        try:
            args = parser.parse_args(shlex.split(cmd)[1:])
        except SystemExit:
            pytest.fail(f"README command does not parse: {cmd}")
        check = getattr(args, "check", None)  # rules between options, checked before any work
        if check is not None:
            check(args)


def test_readme_check_catches_a_c_export_without_out():
    from bemlearn.cli.main import build_parser

    args = build_parser().parse_args(["export", "RUN", "--format", "c"])
    with pytest.raises(ValueError, match="--out DIR"):
        args.check(args)


def test_readme_links_and_named_files_exist():
    text = (ROOT / "README.md").read_text()
    links = [m.split("#")[0] for m in re.findall(r"\]\(([^)\s]+)\)", text) if "://" not in m]
    named = re.findall(r"(?<![\w/.])((?:configs|docs|tests/robots|scripts|examples)/[\w./-]+\.(?:yaml|md|xml|sh|py))", text)
    missing = sorted({p for p in links + named if not (ROOT / p).exists()})
    assert not missing, f"README names files that do not exist: {missing}"
