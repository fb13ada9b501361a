#!/usr/bin/env python
r"""Refit a family run's collected data another way and score it against the robot's oracle.

A study tool for docs/family.md: it separates what limits a learned BEM (the excitation's reach, the
derivative estimates, the draw of training rows) without collecting again.  RUN_DIR is a run folder of
``python -m bemlearn bench family run`` (``config.yaml`` naming the robot file, ``data.npz``, and for
``--truth`` / ``--errors`` the simulator's ``data.truth.npz``); the oracle is the robot's JSON beside its
MJCF (``bemlearn bench family generate``).

Modes:

- ``--set SECTION.KEY=VALUE ...``: train and export with ``bemlearn train`` / ``bemlearn export`` on the
  run's data, the run's config changed by the given keys (YAML values), into ``--out``; scored as the bench
  scores a run (:func:`bemlearn.bench.family.score.compare_predictor`: RMSE, searched max, gain over the
  oracle's design region).  With no ``--set`` it reproduces the run's own predictor.
- ``--truth``: the same training rows with the simulator's exact q, q̇, q̈ (no sensor, no estimator) and the
  run's GP settings, fitted in memory and scored alike.
- ``--errors``: per GP input, the std of (estimated − exact) over the training rows relative to the exact
  column's std, and their correlation (negative: the estimate is the exact signal shrunk, i.e. smoothed).

Examples::

    python scripts/family_refit.py runs/fam/runs/fam0_059 --out /tmp/r1 --set dataset.seed=1
    python scripts/family_refit.py runs/fam/runs/fam0_059 --truth
    python scripts/family_refit.py runs/fam/runs/fam0_059 --errors
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import yaml


def _config(run: Path) -> dict[str, Any]:
    path = run / "config.yaml"
    if not path.is_file():
        sys.exit(f"{path}: no such file (RUN_DIR must be a run folder of 'bemlearn bench family run')")
    cfg = yaml.safe_load(path.read_text())
    if not isinstance(cfg, dict) or not isinstance(cfg.get("robot"), str):
        sys.exit(f"{path}: expected a resolved run config with a 'robot' file")
    return cfg


def _truth(cfg: dict[str, Any]) -> tuple[str, dict]:
    xml = Path(cfg["robot"])
    oracle = xml.with_suffix(".json")
    if not oracle.is_file():
        sys.exit(f"{oracle}: no oracle beside the robot file (write the family with 'bemlearn bench family generate')")
    return xml.read_text(), json.loads(oracle.read_text())


def _score(predictor: Any, xml: str, truth: dict) -> dict:
    """The bench's score of a predictor file, or of an in-memory object with the predictor's three methods."""
    from bemlearn.bench.family.score import compare_module, compare_predictor

    if isinstance(predictor, Path):
        return compare_predictor(predictor, xml, truth)
    return compare_module(predictor, xml, truth, where="the in-memory fit")


def _line(name: str, what: str, r: dict) -> str:
    return f"{name}  {what}: oracle RMSE {r['rmse']:.4f}, max {r['max_abs']:.4f} (sampled {r['max_sampled']:.4f}), gain {r['gain']:.3f}"


def refit(run: Path, out: Path, sets: list[str]) -> str:
    cfg = _config(run)
    for item in sets:
        key, sep, value = item.partition("=")
        section, dot, name = key.partition(".")
        if not sep or not dot or not isinstance(cfg.get(section), dict):
            sys.exit(f"--set {item!r}: expected SECTION.KEY=VALUE with SECTION one of the config's sections")
        cfg[section][name] = yaml.safe_load(value)
    if out.exists():
        sys.exit(f"{out}: exists; give a new --out folder")
    out.mkdir(parents=True)
    (out / "config.yaml").write_text(yaml.safe_dump(cfg))
    for cmd in (["train", str(out / "config.yaml"), "--data", str(run / "data.npz"), "--out", str(out / "run"), "--no-progress"],
                ["export", str(out / "run"), "--format", "torchscript"]):
        done = subprocess.run([sys.executable, "-m", "bemlearn", *cmd], capture_output=True, text=True)
        if done.returncode != 0:
            sys.exit(f"bemlearn {cmd[0]} failed ({done.returncode}):\n{done.stderr[-2000:]}")
    xml, truth = _truth(cfg)
    return _line(run.name, f"refit {' '.join(sets) or '(as run)'}", _score(out / "run" / "bem_predictor.pt", xml, truth))


def _datasets(run: Path, cfg: dict[str, Any]):
    from bemlearn.config import from_dict
    from bemlearn.data.dataset import DatasetConfig, build_datasets
    from bemlearn.data.features import gp_inputs
    from bemlearn.data.trajectory_io import read_trajectory

    train = build_datasets(read_trajectory(run / "data.npz"), from_dict(DatasetConfig, cfg["dataset"])).train
    exact_path = run / "data.truth.npz"
    if not exact_path.is_file():
        sys.exit(f"{exact_path}: no such file (the simulator's exact states are written by 'bemlearn collect')")
    exact = np.load(exact_path)
    u = train.meta.unactuated_index
    rows = train.row.numpy()
    x_exact = gp_inputs(exact["q"][rows], exact["qd"][rows], exact["qdd"][rows], unactuated_index=u)
    return train, x_exact, exact["q"][rows, u]


def truth_fit(run: Path) -> str:
    import torch

    from bemlearn.config import from_dict
    from bemlearn.fitting.fit import train_gp
    from bemlearn.fitting.gp_config import GPConfig
    from bemlearn.models.freeze import predictor_state

    cfg = _config(run)
    train, x_exact, y_exact = _datasets(run, cfg)
    x, y = torch.from_numpy(x_exact), torch.from_numpy(np.ascontiguousarray(y_exact))
    xm, xs, ym, ys = x.mean(0), x.std(0), y.mean(), y.std()
    model, lik, _ = train_gp((x - xm) / xs, (y - ym) / ys, config=from_dict(GPConfig, cfg["train"]))
    state = predictor_state(model, lik, x_mean=xm, x_std=xs, y_mean=ym, y_std=ys, input_names=train.input_names, n_train=len(x))
    m = len(train.meta.joint_names) - 1
    names = [n[len("qdd_"):] for n in train.input_names[:m]]

    class InMemory:
        def metadata(self) -> str:
            return json.dumps({"actuated_names": names})

        def __call__(self, xa: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:   # x_0^e: q̈_u = q̇_u = 0
            return state.predict_reference(torch.cat([xa, torch.zeros(len(xa), 2, dtype=xa.dtype)], 1))

        def bem_mean(self, xa: torch.Tensor) -> torch.Tensor:
            return self(xa)[0]

    xml, truth = _truth(cfg)
    return _line(run.name, f"exact q, q̇, q̈ on the run's {len(x)} training rows", _score(InMemory(), xml, truth))


def estimate_errors(run: Path) -> str:
    cfg = _config(run)
    train, x_exact, y_exact = _datasets(run, cfg)
    lines = [f"{run.name}  estimated − exact over {len(x_exact)} training rows (std relative to the exact column's std; correlation with it):"]
    for name, est, ex in zip(train.input_names, train.x.numpy().T, x_exact.T):
        err = est - ex
        lines.append(f"  {name:16s} {err.std() / ex.std():.3f}  corr {np.corrcoef(err, ex)[0, 1]:+.3f}")
    lines.append(f"  label {train.output_name}: error std {np.std(train.y.numpy() - y_exact):.2e}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run_dir", type=Path, help="a run folder of 'bemlearn bench family run'")
    parser.add_argument("--out", type=Path, help="new folder for the refit (with --set or for a plain refit)")
    parser.add_argument("--set", dest="sets", nargs="*", default=[], metavar="SECTION.KEY=VALUE", help="config changes (YAML values)")
    parser.add_argument("--truth", action="store_true", help="fit the exact q, q̇, q̈ of the same training rows")
    parser.add_argument("--errors", action="store_true", help="print the derivative estimates' errors against the exact ones")
    args = parser.parse_args(argv)
    if not (args.truth or args.errors or args.out):
        parser.error("give --out (a refit), --truth or --errors")
    if args.sets and not args.out:
        parser.error("--set needs --out")
    if args.out:
        print(refit(args.run_dir, args.out, args.sets))
    if args.truth:
        print(truth_fit(args.run_dir))
    if args.errors:
        print(estimate_errors(args.run_dir))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
