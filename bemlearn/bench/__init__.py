"""Benchmarks behind ``bemlearn bench`` (kept out of the timed test suite)."""

from typing import TYPE_CHECKING

from bemlearn._lazy import lazy_namespace

if TYPE_CHECKING:  # imported on first use: bemlearn._lazy
    from bemlearn.bench.bem_train_bench import bench_bem_training
    from bemlearn.bench.derivatives_bench import run_derivatives_bench
    from bemlearn.bench.gpdm_bench import run_gpdm_bench
    from bemlearn.bench.import_bench import bench_import_speed, bench_model_free_accuracy
    from bemlearn.bench.predict_bench import format_predict_bench, run_predict_bench
    from bemlearn.bench.sim_bench import format_sim_bench, run_sim_bench
    from bemlearn.bench.train_bench import bench_train

__all__ = [
    "bench_bem_training",
    "bench_import_speed",
    "bench_model_free_accuracy",
    "bench_train",
    "format_predict_bench",
    "format_sim_bench",
    "run_derivatives_bench",
    "run_gpdm_bench",
    "run_predict_bench",
    "run_sim_bench",
]

__getattr__, __dir__ = lazy_namespace(__name__, __file__)
