"""``bemlearn excite CONFIG [--out FILE]``: a reference schedule for a rig's balancing loop (bemlearn.pipeline.excite)."""

from __future__ import annotations

from pathlib import Path

__all__ = ["add_parser"]


def add_parser(sub) -> None:
    p = sub.add_parser(
        "excite",
        help="write a reference schedule (sines on the actuated reference) that lets a rig's balancing loop resolve the BEM",
        description="From the config's data (their own scales) or robot (its model), write sums of sines to add to the "
        "actuated reference of the rig's own balancing controller during balance — several frequencies, so that the "
        "passive joint's response ratio varies and the data reach the BEM's queries — and say how long to log "
        "(bemlearn.pipeline.excite, docs/verdict.md).",
    )
    p.add_argument("config", type=Path, help="pipeline YAML with data: (a data-only config) and/or robot:")
    p.add_argument("--out", type=Path, default=None,
                   help="schedule file, .yaml (sines, phases per trial) or .csv (trial, t, offsets and their rates); "
                        "default: print the schedule only")
    p.add_argument("--seed", type=int, default=0, help="seed of the per-trial phases (default 0)")
    p.add_argument("--force", action="store_true", help="replace FILE if it exists")
    p.set_defaults(func=run)


def run(args) -> int:
    from bemlearn.pipeline.excite import excitation_schedule, write_schedule
    from bemlearn.pipeline.preflight import preflight

    cfg = preflight(config=args.config, outputs=[args.out] if args.out else [],
                    out_dir=args.out.parent if args.out else None, force=args.force).pipeline_config()
    sched = excitation_schedule(cfg, seed=args.seed)
    print(f"reference schedule from the {sched['source']}; frequencies from {sched['frequency_basis']}:")
    for name, j in sched["joints"].items():
        u = j["unit"]
        print(f"  {name}: " + ", ".join(f"{c['amplitude']:.3g} {u} at {c['frequency_hz']:.3g} Hz" for c in j["sines"])
              + f"  (peak {j['peak']:.3g} {u}, {j['peak_acceleration']:.3g} {u}/s²; limited by {'; '.join(j['limited_by'])})")
    un = sched["unactuated"]
    if any(abs(v) > 0 for v in un["static_slope"].values()):
        print(f"  {un['name']}: its reference moves with them by " + ", ".join(f"{v:+.3g} {un['unit']} per unit of {k}"
                                                                         for k, v in un["static_slope"].items())
              + " (where it rests for that actuated position)")
    total = sched["trials"] * sched["log_seconds_per_trial"]
    print(f"log {sched['trials']} trials × {sched['log_seconds_per_trial']:g} s ({total / 60:.1f} min) at {sched['rate_hz']:g} Hz, "
          "each with its own phases, while the balancing controller tracks these offsets; then import and run again")
    if args.out:
        print(f"wrote {write_schedule(sched, args.out)}")
    return 0
