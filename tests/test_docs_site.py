"""The API reference site builds from the docstrings with warnings as errors (what ``.ci/run`` runs), and reads well.

A docstring griffe cannot read (two parameters on one ``Args:`` line, a parameter that is not in the
signature) fails ``mkdocs build --strict``; this test finds it with the suite instead of in CI.  What the
strict build does not catch is checked on the built HTML: no Sphinx role shown literally (the docstrings'
``:func:`x``` become links through ``scripts/griffe_sphinx_roles.py``), no grouped attribute turned into a
broken table row (``rmse, max_abs: …`` gives a "Name" cell ``rmse,``), and wide tables scroll.
"""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.file_module import load_file_module

ROOT = Path(__file__).resolve().parents[1]
HAVE_DOCS = importlib.util.find_spec("mkdocs") is not None and importlib.util.find_spec("mkdocstrings") is not None

#: A Sphinx role as the site would show it: ``:func:`` before the code the Markdown made of its backticks.
LITERAL_ROLE = re.compile(r":(?:py:)?(?:func|meth|attr|class|mod|data|exc|obj|const):(?:<code>|`)")
#: A table's "Name" cell (mkdocstrings' attribute and parameter tables).
NAME_CELL = re.compile(r"<td><code>(?:<span[^>]*>)?([^<]*)(?:</span>)?</code></td>")


def site_problems(site: Path) -> dict[str, list[str]]:
    """Per page: each literal Sphinx role and each name cell of a grouped entry (``rmse,``)."""
    out: dict[str, list[str]] = {}
    for page in sorted(site.rglob("*.html")):
        text = page.read_text()
        found = [m.group(0) for m in LITERAL_ROLE.finditer(text)]
        found += [f"grouped name cell {c!r}" for c in NAME_CELL.findall(text) if c.rstrip().endswith(",")]
        if found:
            out[str(page.relative_to(site))] = found
    return out


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    if not HAVE_DOCS:
        pytest.skip("the docs extra is not installed (pip install -e '.[docs]')")
    out = tmp_path_factory.mktemp("docs") / "site"
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)],
                          cwd=ROOT, capture_output=True, text=True, timeout=600, env=env)
    warnings = [line for line in done.stderr.splitlines() if "WARNING" in line]
    assert done.returncode == 0 and not warnings, "\n".join(warnings) or done.stderr[-2000:]
    return out


def test_api_reference_builds_without_warnings(site):
    assert (site / "api" / "robots" / "index.html").is_file()


def test_no_literal_sphinx_roles_and_no_broken_attribute_tables(site):
    problems = site_problems(site)
    assert not problems, problems


def test_roles_became_links(site):
    """The roles are cross-references now: e.g. the models page links robust_cholesky to its entry."""
    text = (site / "api" / "models" / "index.html").read_text()
    assert re.search(r'<a class="autorefs autorefs-internal"[^>]*href="[^"]*#bemlearn\.models\.[\w.]*robust_cholesky"><code>robust_cholesky</code></a>',
                     text)
    assert len(re.findall(r'class="autorefs autorefs-internal"', text)) >= 10  # the page had 15 roles


def test_wide_tables_scroll(site):
    css = (site / "stylesheets" / "extra.css").read_text()
    assert "overflow-x: auto" in css
    assert 'href="../stylesheets/extra.css"' in (site / "config" / "index.html").read_text()


def test_the_checks_catch_a_literal_role_and_a_grouped_attribute(tmp_path):
    """The two checks on a planted page (they must be able to fail)."""
    (tmp_path / "a.html").write_text("<p>see :func:<code>bemlearn.models.solver.robust_cholesky</code></p>"
                                     '<td><code><span title="x.rmse,">rmse,</span></code></td><td><code>max_abs</code></td>')
    (tmp_path / "b.html").write_text('<p>:attr:`T`</p><td><code>T_np,</code></td>')
    (tmp_path / "ok.html").write_text('<p><a class="autorefs"><code>robust_cholesky</code></a></p><td><code>rmse</code></td>')
    problems = site_problems(tmp_path)
    assert set(problems) == {"a.html", "b.html"}
    assert problems["a.html"] == [":func:<code>", "grouped name cell 'rmse,'"]
    assert problems["b.html"] == [":attr:`", "grouped name cell 'T_np,'"]


def test_the_role_extension_resolves_relative_names():
    """``scripts/griffe_sphinx_roles.py`` on a small package: dotted, relative (from the object outward) and
    ``~`` targets become optional autorefs; an unknown name stays plain code."""
    griffe = pytest.importorskip("griffe", reason="the docs extra is not installed (pip install -e '.[docs]')")

    mod = load_file_module(ROOT / "scripts" / "griffe_sphinx_roles.py")
    code = {"__init__.py": "", "sub.py": (
        'def helper():\n    """Help."""\n\n\n'
        'class Thing:\n    """Uses :func:`helper`, :meth:`go`, :func:`~pkg.sub.helper`, :mod:`pkg.sub` and :func:`nowhere`."""\n\n'
        '    def go(self):\n        """Go."""\n')}
    with griffe.temporary_visited_package("pkg", code, extensions=griffe.load_extensions(mod.SphinxRoles())) as pkg:
        doc = pkg["sub.Thing"].docstring.value
    assert doc == ('Uses <autoref identifier="pkg.sub.helper" optional><code>helper</code></autoref>, '
                   '<autoref identifier="pkg.sub.Thing.go" optional><code>go</code></autoref>, '
                   '<autoref identifier="pkg.sub.helper" optional><code>helper</code></autoref>, '
                   '<autoref identifier="pkg.sub" optional><code>pkg.sub</code></autoref> and <code>nowhere</code>.')
