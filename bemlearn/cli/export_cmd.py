"""``bemlearn export RUN_DIR [--out FILE] [--format torchscript|pt2|both|aoti]``;
``bemlearn export RUN_DIR --format c --out DIR [--prefix bem] [--dtype float64|float32] [--force]``.

Writes the BEM predictor of a trained run (``RUN_DIR/bem_predictor.pt`` by default), a
TorchScript module that loads with ``torch.jit.load`` without bemlearn; see
docs/predictor-contract.md.  Each file is loaded back and checked against the dense
posterior before the command succeeds.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from bemlearn.errors import ArgumentError

__all__ = ["add_parser", "check_args", "run"]


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "export",
        help="write the BEM predictor (TorchScript .pt / torch.export .pt2 / AOTInductor package) of a trained run",
        description="Write RUN_DIR/bem_predictor.pt: forward(x) -> (mean, std) of the learned BEM "
        "(eq. 12, 14) for x = [qdd_a, qd_a, q_a] float64 (B, 3m), plus bem_mean(x), predict_full(x) "
        "and metadata().  The file loads with torch.jit.load, without bemlearn.",
    )
    parser.add_argument("run_dir", metavar="RUN_DIR", type=Path, help="run directory holding checkpoint.pt (or the checkpoint file)")
    parser.add_argument("--out", metavar="FILE", type=Path, default=None, help="output file (default RUN_DIR/bem_predictor.pt, .pt2 or _aoti.pt2); with --format c the output folder (required)")
    parser.add_argument(
        "--format",
        dest="fmt",
        choices=("torchscript", "pt2", "both", "aoti", "c"),
        default="torchscript",
        help="torchscript (.pt, default), pt2 (torch.export), both (.pt and .pt2 side by side), aoti "
        "(AOTInductor package RUN_DIR/bem_predictor_aoti.pt2, compiled with the C++ compiler for this "
        "machine's CPU, 1-2 min; loads in Python and in C++ with torch::inductor::AOTIModelPackageLoader), or c "
        "(--out DIR gets <prefix>_predictor.h/.c, C99 + libm; docs/c-export.md)",
    )
    _add_c_arguments(parser)
    parser.add_argument("--no-verify", action="store_true", help="skip reloading and checking the written file(s)")
    parser.add_argument("--force", action="store_true", help="replace existing predictor file(s) (any --format)")
    parser.set_defaults(func=run, check=check_args)


def _add_c_arguments(parser: argparse.ArgumentParser) -> None:
    c = parser.add_argument_group("--format c")
    c.add_argument("--prefix", default="bem", help="C identifier prefixed to every name (default bem: bem_mean, ...)")
    c.add_argument("--dtype", choices=("float64", "float32"), default="float64", help="C floating type (default float64)")


def check_args(args: argparse.Namespace) -> None:
    """The rules between options that argparse cannot state, checked before any work (and by the
    README's test of the commands it shows)."""
    if args.fmt == "c" and args.out is None:
        raise ArgumentError("--format c: give the output folder with --out DIR")
    if args.fmt != "c" and (args.prefix != "bem" or args.dtype != "float64"):
        raise ArgumentError("--prefix and --dtype apply to --format c only")


def _run_c(args: argparse.Namespace) -> int:
    from bemlearn.export.c_export import export_c
    from bemlearn.export.c_source import check_prefix
    from bemlearn.outputs import claim_outputs

    names = [f"{check_prefix(args.prefix)}_predictor.h", f"{args.prefix}_predictor.c"]
    # the folder is checked writable and locked before the work; both files or neither
    with claim_outputs(args.out, entries=names, force=args.force, what="export") as out:
        paths = export_c(args.run_dir, out, prefix=args.prefix, dtype=args.dtype, force=args.force)
    for path in paths:
        print(f"wrote {path}")
    return 0


def run(args: argparse.Namespace) -> int:
    check_args(args)
    if args.fmt == "c":
        return _run_c(args)
    from bemlearn.export.export_run import export_run, export_targets
    from bemlearn.outputs import claim_outputs

    targets = export_targets(args.run_dir, out=args.out, fmt=args.fmt)
    # the folder is checked writable and locked before the work; all files or none
    with claim_outputs(targets[0].parent, entries=[p.name for p in targets], force=args.force, what="export"):
        written = export_run(args.run_dir, out=args.out, fmt=args.fmt, verify=not args.no_verify, force=args.force)
    for path in written:
        print(f"wrote {path}")
    return 0
