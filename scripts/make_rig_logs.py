"""Write logger-style CSV files (one per trial) and their import map, from simulated Furuta data.

    python scripts/make_rig_logs.py --out logs/ [--data data/furuta_excitation.npz | --collect N]
        [--unit deg|counts] [--flip alpha] [--jitter-us 20] [--drop 0.002] [--seed 0]
        [--no-header] [--delimiter comma|semicolon|tab|space] [--minimal]
        [--overrun-prob P --overrun-max-ms MS] [--clock-drift D]

``--data`` writes an existing trajectory file's trials (default: the shipped Furuta data);
``--collect N`` simulates N fresh excitation trials of the Furuta (``configs/furuta.yaml``'s
collect section) first.  The files follow :mod:`bemlearn.data.rig_logs` (degrees or counts,
flipped signs, ms stamps with jitter and dropped samples, extra columns); ``OUT/map.yaml`` is
the map that imports them back:

    python -m bemlearn data import logs/episode_*.csv --map logs/map.yaml --out imported.npz
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import yaml

from bemlearn.data import RigLogStyle, read_trajectory, rig_log_map, write_rig_logs

DELIMITERS = {"comma": ",", "semicolon": ";", "tab": "\t", "space": " "}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, required=True, help="folder for the CSV files and map.yaml")
    p.add_argument("--data", type=Path, default=Path("data/furuta_excitation.npz"), help="trajectory file to write out")
    p.add_argument("--collect", type=int, default=None, metavar="N", help="simulate N Furuta trials instead of --data")
    p.add_argument("--config", type=Path, default=Path("configs/furuta.yaml"), help="collect section for --collect")
    p.add_argument("--unit", choices=["deg", "counts"], default="deg")
    p.add_argument("--counts-per-rev", type=int, default=4096)
    p.add_argument("--flip", nargs="*", default=["alpha"], help="joints written with the opposite sign")
    p.add_argument("--jitter-us", type=float, default=20.0, help="timestamp jitter std, µs")
    p.add_argument("--drop", type=float, default=0.002, help="probability of a dropped sample")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-header", action="store_true", help="no preamble and no header line (the map names the columns)")
    p.add_argument("--delimiter", choices=sorted(DELIMITERS), default="comma", help="field separator (default comma)")
    p.add_argument("--minimal", action="store_true", help="only t, the joints and the input")
    p.add_argument("--overrun-prob", type=float, default=0.0, help="probability that the loop overruns at a sample")
    p.add_argument("--overrun-max-ms", type=float, default=0.0, help="largest overrun, ms (never caught up)")
    p.add_argument("--clock-drift", type=float, default=0.0, help="relative drift of the stamping clock, e.g. 0.02")
    args = p.parse_args()
    if args.collect is not None:
        from bemlearn.pipeline.resolve import load_pipeline_config
        from bemlearn.sim.collect import collect

        cfg = dataclasses.replace(load_pipeline_config(args.config).collect, n_trials=args.collect, seed=args.seed)
        traj, _ = collect("furuta", cfg)
    else:
        traj = read_trajectory(args.data)
    style = RigLogStyle(angle_unit=args.unit, counts_per_rev=args.counts_per_rev, flip=tuple(args.flip),
                        jitter_s=args.jitter_us * 1e-6, drop_prob=args.drop, seed=args.seed, header=not args.no_header,
                        delimiter=DELIMITERS[args.delimiter], minimal=args.minimal, overrun_prob=args.overrun_prob,
                        overrun_max_s=args.overrun_max_ms * 1e-3, clock_drift=args.clock_drift)
    paths = write_rig_logs(traj, args.out, style)
    (args.out / "map.yaml").write_text(yaml.safe_dump(rig_log_map(traj, style), sort_keys=False))
    print(f"wrote {len(paths)} files and {args.out / 'map.yaml'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
