#!/usr/bin/env python
r"""Compare two run ``metrics.json`` files key by key: ``scripts/diff_metrics.py A/metrics.json B/metrics.json``.

Every leaf is named by its dotted path (``closed_loop.model.tracking_rmse``, ``bem_slices.slices[0].qd``).
A key present in one file only, or whose values differ, is printed with both values; numbers that
differ are marked ``printed`` when they differ at the digits a report prints (``--digits``
significant digits, default 4) and ``exact`` when they agree there and differ only beyond.
Strings are compared with each file's own run folder replaced by ``<run>`` (a run records its
data file's path).

Keys matching ``--ignore`` are skipped (e.g. ``--ignore '^robot\.mjcf$'`` for the robot file of two
source trees).  Wall-clock measurements (``--timing``, default: keys ending in ``seconds``, ``real_time_factor``,
``tick_us``) differ from run to run; they are listed apart and do not count.

Exit status: 0 when nothing else differs, 1 otherwise (2 for unreadable files).
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

#: Keys that hold wall-clock measurements (regular expressions on the dotted key).
TIMING = (r"(^|\.)seconds$", r"(^|\.)real_time_factor$", r"(^|\.)tick_us(\.|$)")


def flatten(doc: Any, prefix: str = "") -> Iterator[tuple[str, Any]]:
    """``(dotted key, leaf value)`` of a JSON document, lists indexed as ``key[i]``."""
    if isinstance(doc, dict):
        if not doc and prefix:
            yield prefix, {}
        for key, value in doc.items():
            yield from flatten(value, f"{prefix}.{key}" if prefix else str(key))
    elif isinstance(doc, list):
        if not doc and prefix:
            yield prefix, []
        for i, value in enumerate(doc):
            yield from flatten(value, f"{prefix}[{i}]")
    else:
        yield prefix, doc


def _number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def compare(a: Any, b: Any, *, digits: int) -> str | None:
    """``None`` when ``a`` and ``b`` are equal; else ``"printed"`` (they differ at ``digits`` significant
    digits), ``"exact"`` (numbers equal there, different beyond) or ``"value"`` (anything else)."""
    if _number(a) and _number(b):
        fa, fb = float(a), float(b)
        if fa == fb or (math.isnan(fa) and math.isnan(fb)):
            return None
        return "exact" if f"{fa:.{digits}g}" == f"{fb:.{digits}g}" else "printed"
    return None if a == b else "value"


def diff(a: dict, b: dict, *, digits: int = 4, folders: tuple[str, str] = ("", ""),
         timing: tuple[str, ...] = TIMING, ignore: tuple[str, ...] = ()) -> tuple[list[tuple[str, Any, Any, str]], list[tuple[str, Any, Any, str]]]:
    """The differing keys of two metrics documents: ``(differences, timing differences)``, each a list of
    ``(key, value in a, value in b, kind)`` (``kind``: ``printed``, ``exact``, ``value``, ``only in A/B``)."""
    fa, fb = dict(flatten(a)), dict(flatten(b))
    patterns = [re.compile(p) for p in timing]
    skipped = [re.compile(p) for p in ignore]
    out: list[tuple[str, Any, Any, str]] = []
    timed: list[tuple[str, Any, Any, str]] = []
    for key in [*fa, *(k for k in fb if k not in fa)]:
        if any(p.search(key) for p in skipped):
            continue
        va, vb = fa.get(key, "<missing>"), fb.get(key, "<missing>")
        if key not in fb or key not in fa:
            kind: str | None = "only in A" if key in fa else "only in B"
        else:
            if isinstance(va, str) and isinstance(vb, str) and all(folders):
                va, vb = va.replace(folders[0], "<run>"), vb.replace(folders[1], "<run>")
            kind = compare(va, vb, digits=digits)
        if kind is not None:
            (timed if any(p.search(key) for p in patterns) else out).append((key, va, vb, kind))
    return out, timed


def _read(path: Path) -> dict | str:
    """The JSON object in ``path``, or why it cannot be read."""
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        return f"diff_metrics: cannot read {path}: {exc}"
    return doc if isinstance(doc, dict) else f"diff_metrics: {path} holds no JSON object"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("a", type=Path, help="first metrics.json")
    p.add_argument("b", type=Path, help="second metrics.json")
    p.add_argument("--digits", type=int, default=4, help="significant digits a report prints (default 4)")
    p.add_argument("--timing", action="append", metavar="REGEX",
                   help=f"keys that hold wall-clock measurements, listed apart (default: {' '.join(TIMING)})")
    p.add_argument("--ignore", action="append", default=[], metavar="REGEX", help="keys to skip (repeatable)")
    args = p.parse_args(argv)
    if args.digits < 1:
        p.error(f"--digits: expected a positive integer, got {args.digits}")
    a, b = _read(args.a), _read(args.b)
    for problem in (x for x in (a, b) if isinstance(x, str)):
        print(problem, file=sys.stderr)
    if not (isinstance(a, dict) and isinstance(b, dict)):
        return 2      # 1 means "they differ"
    folders = (str(args.a.resolve().parent), str(args.b.resolve().parent))
    found, timed = diff(a, b, digits=args.digits, folders=folders, timing=tuple(args.timing or TIMING),
                       ignore=tuple(args.ignore))
    for title, rows in (("differ", found), ("wall-clock measurements (not counted)", timed)):
        if rows:
            print(f"{len(rows)} key(s) {title}:")
            width = max(len(k) for k, *_ in rows)
            for key, va, vb, kind in rows:
                print(f"  {key:<{width}}  {va!r}  {vb!r}  [{kind}]")
    n = sum(1 for *_, kind in found if kind == "printed")
    print(f"{len(flatten_keys(a, b))} keys compared: {len(found)} differ ({n} at {args.digits} significant digits), "
          f"{len(timed)} timing key(s) differ")
    return 1 if found else 0


def flatten_keys(a: dict, b: dict) -> set[str]:
    """Every key of either document."""
    return {k for k, _ in flatten(a)} | {k for k, _ in flatten(b)}


if __name__ == "__main__":
    sys.exit(main())
