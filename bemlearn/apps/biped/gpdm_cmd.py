"""``bemlearn gpdm CONFIG``: fit a GPDM with χ = c·q (eq. 16–17) to walking or human gait data."""

from __future__ import annotations

import json
from pathlib import Path

from bemlearn.errors import MissingFileError
from bemlearn.examples import config_argument

__all__ = ["add_parser"]

_HUMAN_MAGIC = "# bemlearn human gait"


def add_parser(sub) -> None:
    p = sub.add_parser(
        "gpdm",
        help="fit a GPDM with the chi = c q penalty (eq. 16-17) and write c, latents and metrics",
        description="Fit the GPDM of Section III-C to joint sequences: by default the steps of a walk simulated "
        "from the config's 'walk' section; --data takes a trajectory file (.npz/.csv, one sequence per trial) or "
        "the human gait CSV (data/human_gait/human_gait_right.csv). Writes OUT/{metrics.json,latents.npz,tb/} "
        "(TensorBoard: every objective term per step).",
    )
    p.add_argument("config", type=config_argument, help="biped YAML (its 'gpdm' and 'walk' sections), e.g. configs/biped.yaml")
    p.add_argument("--data", type=Path, help="trajectory file or human gait CSV (default: simulate the config's walk)")
    p.add_argument("--out", type=Path, help="output folder (default runs/gpdm-<timestamp>)")
    p.add_argument("--max-iter", type=int, help="override gpdm.fit.max_iter")
    p.add_argument("--force", action="store_true", help="replace OUT/{metrics.json,latents.npz,tb/} if they exist")
    p.add_argument("--no-progress", action="store_true", help="no progress bars (for logs and scripts)")
    p.set_defaults(func=run)


def _sequences(args, cfg) -> tuple[list, str]:
    """Joint sequences ``(T_i, n)`` rad and a description of where they came from."""
    import dataclasses

    from bemlearn.apps.biped.gpdm_study import human_gait_sequences

    g = cfg.gpdm
    if args.data is None:
        from bemlearn.apps.biped.walker import simulate_walk, walk_trajectories

        walk = cfg.walk
        traj = walk_trajectories(simulate_walk(walk, progress=not args.no_progress))[0]
        where = f"simulated walk ({walk.gait.kind} gait, BEM source {walk.bem_source})"
    elif not args.data.is_file():
        raise MissingFileError(f"--data: {args.data} not found")
    elif args.data.suffix.lower() == ".csv" and args.data.open(encoding="utf-8").readline().startswith(_HUMAN_MAGIC):
        seqs, _ = human_gait_sequences(dataclasses.replace(g.human, path=str(args.data)))
        return seqs, f"human gait {args.data} ({len(seqs)} steps)"
    else:
        from bemlearn.data import read_trajectory

        traj = read_trajectory(args.data)
        where = str(args.data)
    ids = list(traj.trial_ids)
    sel = ids[g.first_step:g.first_step + g.steps] if len(ids) > g.first_step else ids
    seqs = [traj.q[traj.trial == i] for i in sel]
    return seqs, f"{where}: trials {sel[0]}…{sel[-1]} ({len(sel)} sequences, joints {', '.join(traj.meta.joint_names)})"


def run(args) -> int:
    import dataclasses

    from bemlearn.apps.biped.gpdm_study import fit_gpdm_logged
    from bemlearn.apps.biped.pipeline import load_biped_config
    from bemlearn.outputs import claim_outputs
    from bemlearn.pipeline.preflight import preflight

    names = ("metrics.json", "latents.npz", "tb")
    preflight(config=args.config, out_dir=args.out or Path("runs"), outputs=[args.out / n for n in names] if args.out else [],
              force=args.force)
    if args.data is not None and not args.data.is_file():
        raise MissingFileError(f"--data: {args.data} not found")
    cfg = load_biped_config(args.config)
    fit = cfg.gpdm.fit if args.max_iter is None else dataclasses.replace(cfg.gpdm.fit, max_iter=args.max_iter)
    seqs, where = _sequences(args, cfg)
    with claim_outputs(args.out, entries=names, default_name="gpdm", force=args.force, keep_on_interrupt=["metrics.json"],
                       what="gpdm") as out:
        model = fit_gpdm_logged(seqs, out, config=fit, threads=cfg.gpdm.threads, progress=not args.no_progress)
    m = json.loads((out / "metrics.json").read_text())
    print(f"data: {where}")
    print(f"c = [{', '.join(f'{v:+.3f}' for v in model.c.tolist())}] (1/rad, χ = c·(q − q̄))")
    print(f"objective terms: observation {m['observation']:.2f}, dynamics {m['dynamics']:.2f}, penalty {m['penalty']:.3g}; "
          f"corr(latents, c·q) = {m['corr_latent_projection']:.4f}; fit {m['fit_seconds']:.1f} s")
    print(f"wrote {out}/{{metrics.json,latents.npz,tb/}}")
    return 0
