"""The README's claims hold: its API tour gives the right numbers, every ``bemlearn`` command it
shows is accepted as written, every repository path it names exists, every link resolves, and
its quickstart test command is the one .ci/run runs.

References: the tour's model-based BEM against the cart-pole's closed form, its learned BEM
against the Furuta model's BEM (tolerance: the verdict's accuracy target); the commands against
the real parser and, where cheap or harmless, the real command.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import math
import re
import shlex
from pathlib import Path

import pytest
import torch

from bemlearn.cli.main import build_parser, main

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()

#: Names the README uses for the reader's own files and for outputs; not repository paths.
PLACEHOLDERS = {"RUN", "DIR", "my.xml", "my.yaml", "map.yaml", "rig.yaml", "logs/*.csv", "data/rig.npz"}
#: Commands cheap enough to run for real (a robot or config file in, a table out, seconds; the examples copied into an empty folder).
CHEAP = {("robot", "info"), ("robot", "lqr"), ("robot", "list"), ("config", "show"), ("examples", "copy")}


def _commands() -> list[str]:
    """Every ``bemlearn …`` command line of the README: inline code and bash blocks (after ``&&``)."""
    spans = re.findall(r"(?<!`)`([^`\n]+)`(?!`)", README)
    for block in re.findall(r"```bash\n(.*?)```", README, flags=re.S):
        for line in block.splitlines():
            spans.extend(part for part in re.split(r"&&|;", line.split("#")[0]))
    return sorted({s.strip() for s in spans if re.match(r"\s*bemlearn [a-z]", s)})


def test_readme_api_tour_gives_the_right_bems(tmp_path, monkeypatch, capsys):
    """The tour runs as written; its model-based BEM is the cart-pole's closed form and its
    learned (model-free) BEM meets the verdict's accuracy target against the Furuta model."""
    from bemlearn.pipeline.derive import DESIGN_QU
    from bemlearn.pipeline.verdict import RMSE_OF_BOUND
    from bemlearn.robots import load

    blocks = re.findall(r"```python\n(.*?)```", README, flags=re.S)
    assert blocks, "README has no python block"
    monkeypatch.chdir(tmp_path)  # from any folder: the tour reads only files shipped in the package
    ns: dict = {}
    for code in blocks:
        exec(compile(code, "README.md", "exec"), ns)
    capsys.readouterr()
    # a pole on a cart accelerating at a balances at tan φ = a / g (φ = 0 upright, leaning towards
    # +x for φ > 0); the tour asks for a = 1 m/s², and the MJCF's gravity is 9.81
    assert bool(ns["res"].valid.all())
    torch.testing.assert_close(ns["res"].qu, torch.tensor([math.atan2(1.0, 9.81)], dtype=torch.float64), rtol=0, atol=1e-9)
    # the learned BEM at θ̈ = 10 rad/s² (θ = θ̇ = 0) against the shipped Furuta's model-based BEM;
    # tolerance: the verdict's RMSE target over the design region, 0.05 d (0.01 rad)
    x = torch.tensor([[0.0]], dtype=torch.float64)
    truth = load("furuta").bem(x, x, torch.tensor([[10.0]], dtype=torch.float64))
    assert bool(truth.valid.all()) and abs(float(truth.qu[0])) > 0.02  # a BEM off upright: not a trivial zero
    assert abs(float(ns["p"].mean[0] - truth.qu[0])) <= RMSE_OF_BOUND * DESIGN_QU


def test_readme_names_real_commands():
    """Each command the README shows is one the parser knows; a bare ``bemlearn X`` names a subcommand."""
    parser = build_parser()
    commands = _commands()
    assert len(commands) >= 10, commands
    for cmd in commands:
        argv = shlex.split(cmd)[1:]
        if len(argv) == 1:  # `bemlearn sweep`: the command's name in prose
            (subcommands,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
            assert argv[0] in subcommands.choices, cmd
            continue
        with contextlib.redirect_stderr(io.StringIO()):
            try:
                parser.parse_args(argv)
            except SystemExit as exc:
                pytest.fail(f"README command {cmd!r} does not parse (exit {exc.code})")


def test_readme_commands_run(tmp_path, monkeypatch, capsys):
    """The cheap commands run as written (the reader's robot file replaced by a shipped one).  Each
    other command whose inputs are all placeholders is run in an empty folder: it must get past its
    arguments and stop at a missing input file, which it names (no usage error, nothing run)."""
    cfg = tmp_path / "robot.yaml"
    cfg.write_text(f"robot: {ROOT / 'tests' / 'robots' / 'cartpole.xml'}\n")
    cheap_subst = {"my.xml": str(ROOT / "tests" / "robots" / "cartpole.xml"), "my.yaml": str(cfg)}
    work = tmp_path / "empty"
    work.mkdir()
    monkeypatch.chdir(work)
    ran = 0
    for cmd in _commands():
        argv = shlex.split(cmd)[1:]
        if len(argv) == 1:
            continue
        if tuple(argv[:2]) in CHEAP:
            status = main([cheap_subst.get(a, a) for a in argv])
            out = capsys.readouterr()
            assert status == 0, f"{cmd}: exit {status}: {out.err}"
            ran += 1
            continue
        paths = [a for a in argv if not a.startswith("-") and ("/" in a or "." in a or a in PLACEHOLDERS)]
        if not paths or any((ROOT / a).exists() for a in paths):
            continue  # real inputs (e.g. configs/furuta.yaml): the whole run is too long for a test
        status = main(argv)
        err = capsys.readouterr().err
        assert status == 2, f"{cmd}: exit {status}, expected a missing-input error"
        assert any(a in err for a in paths), f"{cmd}: stopped before reading its inputs: {err.strip()}"
        ran += 1
    assert ran >= 5


def _repo_paths() -> set[str]:
    """Repository paths the README names in code (inline, blocks) and links; outputs (``runs/…``),
    the docs build (``site/``), the reader's own files (:data:`PLACEHOLDERS`) and paths outside the clone (``../…``, absent
    from a clean clone in CI) left out.  A token is a path if it has a
    ``/`` and a file extension, a trailing ``/``, or a first folder that exists (``.ci/run``)."""
    code = re.findall(r"```\w*\n(.*?)```", README, flags=re.S) + re.findall(r"(?<!`)`([^`\n]+)`(?!`)", README)
    tokens = {t for c in code for t in re.split(r"[\s\"'(),\[\]{}=]+", c)}
    tokens |= set(re.findall(r"\]\(([^)\s#]+)", README))
    out = set()
    for t in tokens:
        t = t.rstrip(".,;:")
        if (t in PLACEHOLDERS or t.startswith(("runs/", "site/", "../")) or "://" in t
                or not re.fullmatch(r"(\.\./)*[\w.-]+(/[\w.-]+)*/?", t) or "/" not in t):
            continue
        if t.endswith("/") or re.search(r"\.[A-Za-z]+$", t) or (ROOT / t.split("/")[0]).is_dir():
            out.add(t)
    return out


def test_readme_paths_exist():
    paths = _repo_paths()
    for expected in ("configs/furuta.yaml", "tests/robots/cartpole.xml", "data/furuta_excitation.npz",
                     "bemlearn/applications.py", "configs/sweeps/example.yaml", "docs/c-export.md"):
        assert expected in paths, expected  # the scan finds what it should
    missing = sorted(p for p in paths if not (ROOT / p).exists())
    assert not missing, f"README names paths that do not exist: {missing}"


def test_readme_links_resolve():
    links = re.findall(r"\]\(([^)\s]+)\)", README)
    assert links
    for link in links:
        if link.startswith(("http://", "https://")):
            continue
        target, _, anchor = link.partition("#")
        path = ROOT / target
        assert path.exists(), f"README link {link!r}: no such file"
        if anchor:
            slugs = {re.sub(r"[^\w\- ]", "", h).strip().lower().replace(" ", "-")
                     for h in re.findall(r"^#+ (.*)$", path.read_text(), flags=re.M)}
            assert anchor in slugs, f"README link {link!r}: no such heading"


def test_ci_runs_exactly_the_readme_test_command():
    cmds = re.findall(r"```bash\n(pip install torch==2\.13\.0 && pip install -e \"\.\[test\]\" && python -m pytest)\n```", README)
    assert cmds, "README quickstart test command not found"
    ci = (ROOT / ".ci" / "run").read_text().strip().splitlines()
    assert ci[-1] == cmds[0]


def test_readme_says_which_install_line_is_which():
    """The CPU-only and the CUDA torch each have their line, and the README no longer claims the tested
    command installs the CPU build (on the public index on Linux it installs the CUDA one)."""
    quick = README[README.index("## Quickstart"):README.index("## Bring your own robot")]
    cpu = next(line for line in quick.splitlines() if line.startswith("- **CPU-only torch**"))
    cuda = next(line for line in quick.splitlines() if line.startswith("- **CUDA torch**"))
    assert "Get Started" in quick and "CPU" in cpu
    assert "`pip install torch==2.13.0`" in quick[quick.index(cuda):] and "CUDA build" in quick
    assert "puts the CPU build of torch first" not in README


def test_nothing_points_outside_the_repository():
    """The README, the docs, the configs and the package name no file outside the clone (the paper is cited
    by its reference, not by a path on the developers' machine)."""
    outside = re.compile(r"(?:\.\./)+shared/|/work/|shared/paper")
    texts = {"README.md": README}
    for folder, pattern in (("bemlearn", "*.py"), ("docs", "*.md"), ("configs", "*.yaml")):
        texts |= {str(p.relative_to(ROOT)): p.read_text() for p in sorted((ROOT / folder).rglob(pattern)) if "api" not in p.parts}
    assert len(texts) > 100
    bad = sorted(name for name, text in texts.items() if outside.search(text))
    assert not bad, bad
    assert "On the Learned Balance" in README and "F. Han and J. Yi" in README


def test_license_file_matches_the_metadata():
    import tomllib

    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    text = (ROOT / "LICENSE").read_text()
    assert meta["license"] == {"text": "MIT"} and text.startswith("MIT License")
    assert "Copyright (c) 2026 bemlearn developers" in text and "WITHOUT WARRANTY OF ANY KIND" in text


def test_readme_check_catches_a_c_export_without_out():
    from bemlearn.cli.main import build_parser

    args = build_parser().parse_args(["export", "RUN", "--format", "c"])
    with pytest.raises(ValueError, match="--out DIR"):
        args.check(args)
