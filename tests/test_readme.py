"""The README's API tour runs as written, and its quickstart matches .ci/run."""

import re
from pathlib import Path

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
