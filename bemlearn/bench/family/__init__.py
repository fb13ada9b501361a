"""A seeded family of in-class robots with an independent oracle, and the bench that scores the pipeline on it
(issue 28, docs/family.md).

* :mod:`~bemlearn.bench.family.generator` — ``generate_robot(seed, index)`` → MJCF text + ground truth;
* :mod:`~bemlearn.bench.family.oracle` — MuJoCo-only upright, model BEM (Newton on ``mj_inverse``), holdability;
* :mod:`~bemlearn.bench.family.score` — a run's learned BEM and verdict against the oracle, the per-feature table;
* :mod:`~bemlearn.bench.family.family_bench` — write the family to disk, run each robot zero-config, score it.
"""
