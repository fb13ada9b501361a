"""``bemlearn data``: check, convert and import trajectory files.

    bemlearn data check FILE [--robot NAME] [--min-trial-samples K] [--rate-rtol R] [--json]
    bemlearn data convert IN OUT [--force]
    bemlearn data import RAW... --map MAP.yaml --out FILE [--force]

``check`` validates FILE (NPZ or CSV) and prints a summary; on a bad file it exits with
status 2 and an error naming the file, column and row.  ``convert`` rewrites a file in the
format given by OUT's suffix, losslessly (floats as ``%.17g`` in CSV).  ``import`` turns a
logger's CSV files into one trajectory file by a column map (``docs/log-import.md``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from bemlearn.data.limits import JITTER_RTOL, MIN_TRIAL_SAMPLES, RATE_RTOL
from bemlearn.errors import ArgumentError, OutputExistsError

__all__ = ["add_parser", "format_summary"]


def _add_validation_options(parser: argparse.ArgumentParser) -> None:
    """``--min-trial-samples`` and ``--rate-rtol``: the validation limits of ``check`` and ``convert``."""
    parser.add_argument("--min-trial-samples", type=int, default=MIN_TRIAL_SAMPLES, metavar="K",
                        help=f"shortest accepted trial in samples (default {MIN_TRIAL_SAMPLES})")
    parser.add_argument("--rate-rtol", type=float, default=RATE_RTOL, metavar="R",
                        help="accepted relative deviation of each trial's median time step from 1/sample_rate "
                        f"(default {RATE_RTOL:g})")
    parser.add_argument("--jitter-rtol", type=float, default=JITTER_RTOL, metavar="J",
                        help="accepted relative deviation of every single time step from 1/sample_rate "
                        f"(timestamp jitter; default {JITTER_RTOL:g})")


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "data", help="check and convert trajectory files",
        description="Check and convert trajectory files (format: docs/trajectory-format.md).",
    )
    sub = parser.add_subparsers(dest="data_command", metavar="ACTION", required=True)

    check = sub.add_parser("check", help="validate a trajectory file and print a summary")
    check.add_argument("file", type=Path, help="trajectory file (.npz or .csv)")
    check.add_argument("--robot", metavar="NAME", help="also require the joint names of this registered robot")
    _add_validation_options(check)
    check.add_argument("--json", action="store_true", help="print the summary as JSON")
    check.set_defaults(func=run_check)

    convert = sub.add_parser("convert", help="convert between CSV and NPZ (lossless)")
    convert.add_argument("input", type=Path, help="input trajectory file (.npz or .csv)")
    convert.add_argument("output", type=Path, help="output file; its suffix (.npz or .csv) picks the format")
    convert.add_argument("--force", action="store_true", help="overwrite OUT if it exists")
    _add_validation_options(convert)
    convert.set_defaults(func=run_convert)

    imp = sub.add_parser("import", help="import a logger's CSV files by a column map (docs/log-import.md)")
    imp.add_argument("raw", type=Path, nargs="+", metavar="RAW", help="the logger's CSV files, in trial order")
    imp.add_argument("--map", type=Path, required=True, metavar="MAP.yaml", help="the column map")
    imp.add_argument("--out", type=Path, required=True, metavar="FILE", help="output trajectory file (.npz or .csv)")
    imp.add_argument("--force", action="store_true", help="overwrite FILE if it exists")
    imp.set_defaults(func=run_import)
    return parser


def format_summary(path: Path | str, s: dict[str, Any]) -> str:
    """Human-readable lines for :meth:`Trajectory.summary` output ``s``."""
    lengths = s["trial_samples_min_median_max"]
    lines = [
        f"file:         {path}",
        f"robot:        {s['robot']}",
        f"joints:       {', '.join(s['joints'])} (unactuated: {s['unactuated']})",
        f"actuators:    {', '.join(s['actuators'])} [{s['units'].get('u', '?')}]",
        f"trials:       {s['trials']} ({s['failed_trials']} failed"
        + (f": {_ids(s['failed_trial_ids'])})" if s["failed_trials"] else ")"),
        f"samples:      {s['samples']} ({s['duration_s']:.6g} s; per trial min/median/max "
        + (f"{lengths[0]}/{lengths[1]:g}/{lengths[2]})" if lengths else "-)"),
        f"sample rate:  {s['sample_rate_hz']:g} Hz",
        f"ground truth: {'yes (qd, qdd)' if s['ground_truth'] else 'no'}",
    ]
    kinds = s.get("joint_kinds", {})
    if s.get("channels"):
        lines.append(f"channels:     {', '.join(s['channels'])}")
    if s.get("torques"):
        on_qu = " (on the unactuated joint: the BEM assumes none there)" if s["unactuated"] in s["torques"] else ""
        lines.append(f"torques:      {', '.join(s['torques'])}{on_qu}")
    slides = any(k == "slide" for k in kinds.values())
    lines.append("ranges (rad for hinges, m for slides):" if slides else "angle ranges (rad):")
    for joint, rng in s["angle_ranges_rad"].items():
        unit = " m" if kinds.get(joint) == "slide" else ""
        lines.append(f"  {joint:<12} [{rng[0]:+.6g}, {rng[1]:+.6g}]{unit}" if rng else f"  {joint:<12} -")
    before = " — detected in the logged values, before resampling" if s.get("resampled") else ""
    lines.append(("quantization step (rad, m for slides)" if slides else "quantization step (rad)") + before + ":")
    for joint, step in s["quantization_step_rad"].items():
        if step is None:
            lines.append(f"  {joint:<12} none detected")
        else:
            from bemlearn.data.quantization import counts_per_revolution

            counts = counts_per_revolution(step)
            lines.append(f"  {joint:<12} {step:.10g}" + (f" (= 2π/{counts}, {counts} counts/rev)" if counts else ""))
    return "\n".join(lines)


def _ids(ids: list[int], limit: int = 20) -> str:
    shown = ", ".join(str(i) for i in ids[:limit])
    return shown + (f", … ({len(ids) - limit} more)" if len(ids) > limit else "")


def run_check(args: argparse.Namespace) -> int:
    from bemlearn.data.trajectory_io import read_trajectory

    traj = read_trajectory(args.file, robot=args.robot, min_trial_samples=args.min_trial_samples,
                           rate_rtol=args.rate_rtol, jitter_rtol=args.jitter_rtol)
    summary = traj.summary()
    if args.json:
        print(json.dumps({"file": str(args.file), **summary}, indent=2))
    else:
        print(format_summary(args.file, summary))
        print("OK")
    return 0


def run_convert(args: argparse.Namespace) -> int:
    from bemlearn.data.trajectory_io import SUFFIXES, read_trajectory, write_trajectory

    if args.output.suffix.lower() not in SUFFIXES:
        raise ArgumentError(
            f"{args.output}: unsupported output suffix {args.output.suffix!r}; expected one of {list(SUFFIXES)}"
        )
    from bemlearn.files import check_outputs
    from bemlearn.outputs import claim_outputs

    check_outputs([args.output], args.force, what="data convert")
    if args.output.resolve() == args.input.resolve():
        raise ArgumentError(f"{args.output}: output is the input file")
    limits = {"min_trial_samples": args.min_trial_samples, "rate_rtol": args.rate_rtol, "jitter_rtol": args.jitter_rtol}
    # the output folder is checked writable and locked before the input is read
    with claim_outputs(args.output.parent, entries=[args.output.name], force=args.force, what="data convert"):
        traj = read_trajectory(args.input, **limits)
        write_trajectory(traj, args.output, **limits)
    print(f"wrote {args.output} ({traj.n_samples} samples, {len(traj.meta.trial_failed)} trials)")
    return 0


def run_import(args: argparse.Namespace) -> int:
    from bemlearn.data.import_map import load_import_map
    from bemlearn.data.log_import import import_logs
    from bemlearn.data.trajectory_io import SUFFIXES, write_trajectory

    if args.out.suffix.lower() not in SUFFIXES:
        raise ArgumentError(f"{args.out}: unsupported output suffix {args.out.suffix!r}; expected one of {list(SUFFIXES)}")
    from bemlearn.outputs import claim_outputs

    if args.out.exists() and not args.force:
        raise OutputExistsError(f"{args.out}: already exists (use --force to overwrite)")
    if any(args.out.resolve() == p.resolve() for p in args.raw):
        raise ArgumentError(f"{args.out}: output is one of the input files")
    # the output folder is checked writable and locked before the map and the logs are read
    with claim_outputs(args.out.parent, entries=[args.out.name], force=args.force, what="data import"):
        imap = load_import_map(args.map)
        traj = import_logs(args.raw, imap)
        write_trajectory(traj, args.out)
    info = traj.meta.extra["import"]
    filled = (f"{info['filled_samples']} grid samples more than ½ step from any stamp" if info.get("resample") else
              f"{info['filled_samples']} dropped samples interpolated")
    print(f"wrote {args.out} ({traj.n_samples} samples, {len(traj.meta.trial_failed)} trials at "
          f"{traj.meta.sample_rate_hz:g} Hz; {filled}, {info['split_gaps']} trials split at gaps, "
          f"{info['dropped_pieces']} short pieces dropped)")
    for line in import_notes(info):
        print(line)
    print(format_summary(args.out, traj.summary()))
    return 0


def import_notes(info: dict[str, Any]) -> list[str]:
    """The import's lines about resampling, time windows, logged torques and cut last lines (``meta.extra["import"]``), for the user."""
    lines = []
    res = info.get("resample")
    if res:
        share = 100.0 * res["moved"] / max(res["stamps"], 1)
        lines.append(
            f"resampled (time.resample: linear) onto {res['rate_hz']:g} Hz: {res['stamps']} logged samples -> "
            f"{res['samples']}; {res['moved']} ({share:.1f} %) had moved more than {res['tolerance_steps']:g} step off "
            f"the grid; largest overrun {res['largest_overrun_s'] * 1e3:.4g} ms (a step of {res['largest_step_s'] * 1e3:.4g} ms); "
            f"the stamps average {res['stamp_rate_hz']:.6g} Hz"
        )
        steps = {k: v for k, v in info.get("quantization_step", {}).items() if v is not None}
        if steps and res["moved"]:
            lines.append(
                "warning: the interpolated angles of " + ", ".join(steps) + " leave their encoder grid; the steps detected "
                "before resampling are kept in the file (meta.extra['import']['quantization_step']) and shown below"
            )
    for w in info.get("windows", []):
        t0, t1 = ("start" if w["window"][0] is None else f"{w['window'][0]:g}"), ("end" if w["window"][1] is None else f"{w['window'][1]:g}")
        lines.append(f"{w['file']}: {w['key']} = [{t0}, {t1}] {w['unit']}: {w['kept']} of {w['rows']} rows imported")
    for joint, tq in (info.get("torques") or {}).items():
        what = "force" if tq["unit"] == "N" else "torque"
        line = f"logged {what} on {joint}: {tq['rms']:.4g} {tq['unit']} rms, mean {tq['mean']:.4g}, largest {tq['max_abs']:.4g}"
        if tq["unactuated"] and tq["max_abs"] > 0:
            line = (f"warning: the unactuated joint {joint} carries a logged {what} of {tq['rms']:.4g} {tq['unit']} rms (mean "
                    f"{tq['mean']:.4g}, largest {tq['max_abs']:.4g}): the BEM assumes it unactuated (Γ_u = 0), so a map learned "
                    "from these data mixes it in; a run with the robot's model (model:) weighs it against gravity")
        lines.append(line)
    for cut in info.get("cut_last_lines", []):
        lines.append(f"warning: {cut['file']}: line {cut['line']}, the last (no line end), looks cut mid-write "
                     f"({cut['reason']}): not imported")
    return lines
