"""``bemlearn sweep SWEEP.yaml``: a grid of configs, each cell a run folder, on this machine or a Ray cluster."""

from __future__ import annotations

from pathlib import Path

from bemlearn.errors import ArgumentError
from bemlearn.examples import config_argument

__all__ = ["add_parser"]


def add_parser(sub) -> None:
    p = sub.add_parser(
        "sweep",
        help="run a grid of configs (robots, seeds, any config key) as cells, locally or on a Ray cluster",
        description="Run every cell of SWEEP.yaml (base config × grid of dotted keys) into DIR/cells/<cell id>/ (a run "
        "folder as the stage's command writes it, plus cell.json) and write DIR/results.csv, results.json and "
        "summary.png. Every cell is validated before any runs; a failed cell is retried, then recorded; --resume "
        "skips complete cells. Stages: run, train, simulate, and those of installed applications. See docs/sweeps.md.",
    )
    p.add_argument("sweep", type=config_argument, metavar="SWEEP.yaml", help="sweep file: base, grid, stage, resources, retries")
    p.add_argument("--out", type=Path, help="sweep folder (default: a new runs/<sweep name>-<timestamp>)")
    p.add_argument("--backend", choices=["ray", "serial"], default="ray",
                   help="ray: each cell a Ray task (a local Ray instance with this machine's cores unless --address); "
                   "serial: one cell after another in this process (also what ray falls back to when Ray is not installed)")
    p.add_argument("--address", help="a running Ray cluster: auto, HOST:6379 (ray start --head) or ray://HOST:10001")
    p.add_argument("--resume", action="store_true", help="continue the sweep in --out: complete cells are kept and skipped")
    p.add_argument("--force", action="store_true", help="run every cell again, replacing the cell folders in --out")
    p.add_argument("--max-parallel", type=int, default=None, metavar="N",
                   help="at most N cells at once (default: as many as the cluster's CPUs hold at resources.cpus each)")
    p.add_argument("--dry-run", action="store_true", help="validate every cell and list them (id, grid values, complete?)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars (for logs and scripts)")
    p.set_defaults(func=_sweep)


def _sweep(args) -> int:
    from bemlearn.sweep import run_sweep

    if args.resume and args.force:
        raise ArgumentError("--resume and --force: give one (keep the complete cells, or run every cell again)")
    if args.dry_run:
        return _dry_run(args)
    result = run_sweep(args.sweep, args.out, backend=args.backend, address=args.address, resume=args.resume,
                       force=args.force, max_parallel=args.max_parallel, progress=not args.no_progress)
    _print_table(result.columns, result.rows)
    n = len(result.cells)
    now = f"{len(result.ran)} run now on the {result.backend} backend" if result.ran else "nothing to run"
    print(f"{n} cells: {result.n_ok} ok, {result.n_failed} failed ({now}, {n - len(result.ran)} complete before) "
          f"in {result.wall_s:.0f} s")
    print(f"results: {result.out_dir / 'results.csv'}")
    return 1 if result.n_failed else 0


def _dry_run(args) -> int:
    from bemlearn.sweep import expand_cells, load_sweep, read_outcome

    cells = expand_cells(load_sweep(args.sweep))
    for c in cells:
        state = ""
        if args.out is not None:
            o = read_outcome(args.out / "cells" / c.cell_id)
            state = "complete" if o is not None and o.status == "ok" else "to run"
        print(f"{c.index:>4}  {c.cell_id}  {state:<9} {c.label}")
    print(f"{len(cells)} cells, stage {cells[0].stage if cells else '-'}: every config is valid")
    return 0


def _print_table(columns: list[str], rows: list[dict], *, max_rows: int = 60) -> None:
    """The cell, grid, status and first few metric columns as an aligned table."""
    from bemlearn.sweep.results import FIXED_COLUMNS

    start = columns.index(FIXED_COLUMNS[-1]) + 1
    grid = columns[2:columns.index("status")]
    shown = ["cell", *grid, "status", "verdict", "wall_s", *columns[start:start + 3]]

    def fmt(v) -> str:
        if v is None:
            return ""
        if isinstance(v, float):
            return f"{v:.4g}"
        s = str(v)
        return Path(s).name if "/" in s else s

    table = [[c for c in shown]] + [[fmt(r.get(c)) for c in shown] for r in rows[:max_rows]]
    widths = [max(len(row[i]) for row in table) for i in range(len(shown))]
    for row in table:
        print("  ".join(v.ljust(w) for v, w in zip(row, widths)).rstrip())
    if len(rows) > max_rows:
        print(f"… {len(rows) - max_rows} more rows in results.csv")
    for r in rows:
        if r["status"] == "failed":
            print(f"cell {r['cell']} failed: {r['error']}")
