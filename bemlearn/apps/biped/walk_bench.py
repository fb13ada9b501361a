"""``bemlearn bench walks``: how reliably the biped walks, over seeds (Section IV-B).

Issue 7 asks for ≥ 20 consecutive steps without falling on the default and the
human-derived gait, torso unactuated, with the learned torso BEM in the loop.  One walk is
one draw of the initial state and the sensor noise; this benchmark repeats the walk of a
config's ``walk:`` section for ``seeds`` seeds per gait and per torso BEM source (the
model-based BEM of eq. 9 and/or an exported predictor's ``bem_mean``, eq. 14), each with a
seeded perturbation of the initial joint angles (``initial_noise``, rad) and Gaussian
encoder noise (``sensor_noise``, rad, on top of the quantization), and counts the walks
that reach ``steps`` steps.
"""

from __future__ import annotations

import dataclasses
import statistics
import time
from dataclasses import dataclass

from tqdm.auto import tqdm

from bemlearn.errors import ArgumentError

__all__ = ["WalkBenchRow", "run_walk_bench", "format_walk_bench"]


@dataclass(frozen=True)
class WalkBenchRow:
    """One walk: its torso BEM source, gait, seed, steps taken, whether it fell, wall time (s)."""

    source: str
    gait: str
    seed: int
    steps: int
    fell: bool
    seconds: float


def run_walk_bench(walk, *, seeds: int = 20, steps: int = 30, gaits: tuple[str, ...] = ("default", "human"),
                   predictor: str | None = None, model: bool = True, initial_noise: float = 0.02,
                   sensor_noise: float = 0.001, progress: bool = True) -> list[WalkBenchRow]:
    """Walk ``seeds`` seeded walks per gait and per BEM source (module docstring).

    Args:
        walk: a :class:`~bemlearn.apps.biped.walker.WalkConfig` (gait design, gains, sensor, rate).
        seeds: walks per gait and source (seeds 0 … seeds − 1).
        steps: steps each walk is asked for (``max_steps``); it has ``2 s`` per step to take them.
        gaits: gait kinds (``default``, ``human``).
        predictor: an exported ``bem_predictor.pt`` to walk with; ``None``: model BEM only.
        model: also walk with the model-based BEM.
        initial_noise: std of the seeded initial joint-angle perturbation, rad.
        sensor_noise: std of the Gaussian encoder noise, rad.
        progress: show a progress bar.
    """
    from bemlearn.apps.biped.walker import simulate_walk

    if seeds < 1 or steps < 1:
        raise ArgumentError(f"seeds and steps: expected positive integers, got seeds={seeds}, steps={steps}")
    if initial_noise < 0 or sensor_noise < 0:
        raise ArgumentError(f"initial_noise and sensor_noise: expected >= 0 rad, got {initial_noise}, {sensor_noise}")
    sources = (["model"] if model else []) + (["predictor"] if predictor else [])
    if not sources:
        raise ArgumentError("run_walk_bench: nothing to walk with (model=False and no predictor)")
    jobs = [(s, g, k) for s in sources for g in gaits for k in range(seeds)]
    rows = []
    for source, gait, seed in tqdm(jobs, desc="walks", disable=not progress):
        cfg = dataclasses.replace(
            walk, duration_s=2.0 * steps, max_steps=steps, bem_source=source,
            predictor=predictor if source == "predictor" else None, seed=seed, initial_noise=initial_noise,
            gait=dataclasses.replace(walk.gait, kind=gait), sensor=dataclasses.replace(walk.sensor, noise_std=sensor_noise))
        t0 = time.perf_counter()
        r = simulate_walk(cfg, progress=False)
        rows.append(WalkBenchRow(source, gait, seed, len(r.steps), bool(r.fell), time.perf_counter() - t0))
    return rows


def format_walk_bench(rows: list[WalkBenchRow], *, steps: int) -> str:
    """Per (source, gait): walks that reached ``steps`` steps, falls, min / median steps, time."""
    lines = [f"| BEM source | gait | reached {steps} steps | fell | min steps | median steps | s per walk |",
             "| --- | --- | --- | --- | --- | --- | --- |"]
    groups: dict[tuple[str, str], list[WalkBenchRow]] = {}
    for r in rows:
        groups.setdefault((r.source, r.gait), []).append(r)
    for (source, gait), rs in groups.items():
        n = [r.steps for r in rs]
        ok = sum(r.steps >= steps and not r.fell for r in rs)
        lines.append(f"| {source} | {gait} | {ok}/{len(rs)} | {sum(r.fell for r in rs)} | {min(n)} | "
                     f"{statistics.median(n):g} | {statistics.mean(r.seconds for r in rs):.1f} |")
    return "\n".join(lines)
