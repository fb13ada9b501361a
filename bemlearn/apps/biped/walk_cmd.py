"""``bemlearn walk CONFIG``: walk the planar biped in MuJoCo with a chosen torso-BEM source."""

from __future__ import annotations

import json
from pathlib import Path

from bemlearn.errors import ArgumentError, MissingFileError
from bemlearn.examples import config_argument

__all__ = ["add_parser"]


def add_parser(sub) -> None:
    p = sub.add_parser(
        "walk",
        help="walk the 5-link biped with the model-based, learned (predictor) or zero torso BEM",
        description="Simulate the walker of the config's 'walk' section (EIC internal loop on the torso, eq. 3, 8, 9) "
        "and write OUT/{walk.json,walk.npz,walk.truth.npz,walk.png}. Exit code 1 if the walker falls.",
    )
    p.add_argument("config", type=config_argument, help="biped YAML (its 'robot' and 'walk' sections), e.g. configs/biped.yaml")
    p.add_argument("--source", choices=["model", "zero", "predictor"], help="torso BEM source (default: walk.bem_source)")
    p.add_argument("--predictor", type=Path, help="exported bem_predictor.pt (implies --source predictor)")
    p.add_argument("--gait", choices=["default", "human"], help="override walk.gait.kind")
    p.add_argument("--duration", type=float, help="override walk.duration_s (s)")
    p.add_argument("--steps", type=int, help="override walk.max_steps (0: no limit)")
    p.add_argument("--seed", type=int, help="override walk.seed")
    p.add_argument("--out", type=Path, help="output folder (default: a new runs/walk-<timestamp>)")
    p.add_argument("--force", action="store_true", help="replace OUT/walk.* if they exist")
    p.add_argument("--no-progress", action="store_true", help="no progress bars (for logs and scripts)")
    p.set_defaults(func=run)


def run(args) -> int:
    from bemlearn.outputs import claim_outputs
    from bemlearn.pipeline.preflight import preflight

    names = ("walk.json", "walk.npz", "walk.truth.npz", "walk.png")
    preflight(config=args.config, out_dir=args.out or Path("runs"), outputs=[args.out / n for n in names] if args.out else [],
              force=args.force)
    source = args.source or ("predictor" if args.predictor else None)
    if args.predictor is not None and source != "predictor":
        raise ArgumentError(f"--predictor is only used with --source predictor, got --source {source}")
    if args.predictor is not None and not args.predictor.is_file():
        raise MissingFileError(f"--predictor: {args.predictor} not found (expected an exported bem_predictor.pt)")
    with claim_outputs(args.out, entries=names, default_name="walk", force=args.force, what="walk") as args.out:
        return _walk(args)


def _walk(args) -> int:
    import dataclasses

    from bemlearn.apps.biped.walker import load_walk_config, simulate_walk, walk_trajectories
    from bemlearn.data import ground_truth_path, write_trajectory
    from bemlearn.files import atomic_write_text

    cfg = load_walk_config(args.config)
    source = args.source or ("predictor" if args.predictor else cfg.bem_source)
    if args.predictor is not None and source != "predictor":
        raise ArgumentError(f"--predictor is only used with --source predictor, got --source {source}")
    over = {k: v for k, v in (("duration_s", args.duration), ("max_steps", args.steps), ("seed", args.seed)) if v is not None}
    if args.gait:
        over["gait"] = dataclasses.replace(cfg.gait, kind=args.gait)
    predictor = str(args.predictor) if args.predictor is not None else cfg.predictor
    cfg = dataclasses.replace(cfg, bem_source=source, predictor=predictor, **over)
    result = simulate_walk(cfg, progress=not args.no_progress)
    data, truth = walk_trajectories(result)
    write_trajectory(data, args.out / "walk.npz")
    write_trajectory(truth, ground_truth_path(args.out / "walk.npz"))
    m = result.metrics
    atomic_write_text(args.out / "walk.json", json.dumps(m, indent=2, default=float))
    _plot(result, args.out / "walk.png")
    print(f"{m['gait']} gait, BEM source {m['bem_source']}: {m['steps']} steps in {m['duration_s']:.2f} s, fell: {m['fell']}")
    if m["steps"] > 0:
        print(f"step length {m['step_length_mean']:.3f} m, speed {m['speed']:.3f} m/s, torso [{m['torso_min']:+.3f}, "
              f"{m['torso_max']:+.3f}] rad, BEM [{m['qu_e_min']:+.3f}, {m['qu_e_max']:+.3f}] rad, "
              f"controller {m['controller_us_per_tick']:.0f} µs/tick")
    print(f"wrote {args.out}/walk.{{json,npz,truth.npz,png}}")
    return 1 if m["fell"] else 0


def _plot(result, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    r = result
    fig, ax = plt.subplots(3, 1, figsize=(9, 7), sharex=True)
    ax[0].plot(r.t, r.q_meas[:, 0], "k", lw=1, label="torso $q_1$")
    ax[0].plot(r.t, r.qu_e, "C1", lw=1, label=f"BEM $q_1^e$ in the loop ({r.metrics['bem_source']})")
    for a, cols, name in ((ax[1], (1, 3), "hip"), (ax[2], (2, 4), "knee")):
        for j, col in enumerate(cols):
            a.plot(r.t, r.q_meas[:, col], f"C{j}", lw=1, label=f"$q_{col + 1}$ ({name} {j + 1})")
    for a in ax:
        a.set_ylabel("rad")
        a.legend(loc="upper right", fontsize=8)
    ax[2].set_xlabel("t (s)")
    fig.tight_layout()
    from bemlearn.files import atomic_path

    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
