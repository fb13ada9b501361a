"""``bemlearn examples``: the example configs shipped with the package; ``bemlearn examples copy DIR``: a copy to edit."""

from __future__ import annotations

from pathlib import Path

__all__ = ["add_parser"]


def add_parser(sub) -> None:
    p = sub.add_parser("examples", help="list the example configs shipped with bemlearn (`bemlearn run NAME` runs one)",
                       description="List the example configs shipped inside the package. A command's CONFIG argument "
                       "accepts an example's name from any folder (`bemlearn run NAME`, `bemlearn sweep sweeps/NAME`). "
                       "`bemlearn examples copy DIR` copies them, with the robots and sample data they name, into DIR.")
    p.set_defaults(func=_list)
    acts = p.add_subparsers(dest="examples_command", metavar="ACTION")
    cp = acts.add_parser("copy", help="copy the examples (configs/, tests/robots/, data/) into DIR, laid out as in the repository",
                         description="Copy the example configs, the robots and the sample data into DIR (created if "
                         "needed), laid out as in the repository: in DIR, `bemlearn run configs/NAME.yaml` and every "
                         "path of the documentation work. Existing files are kept unless --force.")
    cp.add_argument("dir", type=Path, help="destination folder")
    cp.add_argument("--force", action="store_true", help="replace files that already exist in DIR")
    cp.set_defaults(func=_copy)


def _list(args) -> int:
    from bemlearn.examples import EXAMPLES_DIR, examples

    found = examples()
    width = max(len(n) for n in found)
    print(f"# example configs in {EXAMPLES_DIR / 'configs'} (run one by name: `bemlearn run NAME`, "
          "`bemlearn sweep NAME` for a sweep)")
    for ex in found.values():
        print(f"{ex.name:<{width}}  {ex.kind:<6}  {ex.summary}")
    return 0


def _copy(args) -> int:
    from bemlearn.examples import copy_examples

    written = copy_examples(args.dir, force=args.force)
    print(f"copied {len(written)} files into {args.dir}; run them there (`bemlearn run configs/NAME.yaml`, NAME from "
          "`bemlearn examples`)")
    return 0
