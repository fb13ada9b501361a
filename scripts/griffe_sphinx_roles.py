"""Griffe extension of the API site (mkdocs.yml): the docstrings' Sphinx roles become cross-references.

The docstrings cite other objects the way Sphinx does (``:func:`~bemlearn.models.solver.robust_cholesky```,
``:attr:`T```, ``:mod:`bemlearn.pipeline.derived_defaults```); mkdocstrings does not read roles and would show
them literally.  Once the package is loaded, every role in every docstring is rewritten into an optional
mkdocs-autorefs reference: a link where the site documents the target, plain code where it does not (an
optional reference never fails the strict build).  A name without a dot is looked up from the object outward
(its own members, its class, its module, the package), as Sphinx resolves it; ``~`` shows the last component
only.  The docstrings themselves stay as they are (they read well as plain text and in ``help()``).
"""

from __future__ import annotations

import html
import re
from typing import Any

import griffe

__all__ = ["ROLE", "SphinxRoles"]

#: A Sphinx cross-reference role: ``:func:`target```, ``:py:meth:`~a.b```, ``:class:`title <target>```.
ROLE = re.compile(r":(?:py:)?(?:func|meth|attr|class|mod|data|exc|obj|const|type):`(?P<tilde>~?)(?P<text>[^`]+?)`")


def _lookup(pkg: griffe.Module, path: str) -> Any | None:
    """The object at dotted ``path`` inside ``pkg`` (``None`` if there is none or it cannot be resolved)."""
    if path == pkg.path:
        return pkg
    if not path.startswith(pkg.path + "."):
        return None
    try:
        return pkg[path[len(pkg.path) + 1:]]
    except Exception:  # noqa: BLE001 - a missing member, an alias to another package: not a target here
        return None


def _scopes(obj: Any) -> list[str]:
    """Dotted paths a relative name is tried against, innermost first: the object, its parents, the package."""
    out = []
    while obj is not None:
        out.append(obj.path)
        obj = obj.parent
    return out


def role_to_autoref(match: re.Match[str], obj: Any, pkg: griffe.Module) -> str:
    """One role as ``<autoref identifier=… optional><code>…</code></autoref>`` (plain ``<code>`` when unresolved)."""
    text = match["text"].strip()
    title_target = re.fullmatch(r"(?P<title>.+?)\s*<(?P<target>[^>]+)>", text)
    target = (title_target["target"] if title_target else text).strip().lstrip(".").removesuffix("()")
    shown = title_target["title"] if title_target else (target.rsplit(".", 1)[-1] if match["tilde"] else target)
    found = None
    for candidate in [target] + [f"{scope}.{target}" for scope in _scopes(obj)]:
        found = _lookup(pkg, candidate)
        if found is not None:
            target = candidate
            break
    code = f"<code>{html.escape(shown)}</code>"
    if found is None:
        return code
    return f'<autoref identifier="{html.escape(target)}" optional>{code}</autoref>'


def _objects(obj: Any):
    yield obj
    for member in obj.members.values():
        if not member.is_alias:
            yield from _objects(member)


class SphinxRoles(griffe.Extension):
    """Rewrite Sphinx roles into optional autorefs once the whole package is loaded (module docstring)."""

    def on_package(self, *, pkg: griffe.Module, **kwargs: Any) -> None:
        for obj in _objects(pkg):
            doc = obj.docstring
            if doc is not None and ":" in doc.value and ROLE.search(doc.value):
                doc.value = ROLE.sub(lambda m, o=obj: role_to_autoref(m, o, pkg), doc.value)
