"""``bemlearn config show CONFIG``: the resolved pipeline config, each value with its origin."""

from __future__ import annotations

import json

from bemlearn.examples import config_argument

__all__ = ["add_parser"]


def add_parser(sub) -> None:
    p = sub.add_parser("config", help="show the resolved config: given, derived from the model, or default",
                       description="Inspect pipeline configs. Every key is documented in docs/config.md.")
    cs = p.add_subparsers(dest="config_command", metavar="ACTION", required=True)
    show = cs.add_parser("show", help="print every value of CONFIG with its origin (given / derived / default)",
                         description="Parse CONFIG strictly, derive what the robot's model determines (control rate, "
                         "physics step, excitation, evaluation references, EIC gains) and print every value with its "
                         "origin and, for derived values, how it was derived.")
    show.add_argument("config", type=config_argument, help="pipeline YAML, or the name of a shipped example (`bemlearn examples`)")
    show.add_argument("--json", action="store_true", help="machine-readable output")
    show.set_defaults(func=_show)


def _show(args) -> int:
    from bemlearn.pipeline.resolve import format_resolved, resolve_pipeline_config

    resolved = resolve_pipeline_config(args.config)
    print(json.dumps(resolved.to_json_dict(), indent=2, ensure_ascii=False) if args.json else format_resolved(resolved))
    return 0
