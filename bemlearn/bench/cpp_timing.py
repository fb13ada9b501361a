"""Time the TorchScript file and the AOTInductor package from C++ (libtorch of the torch wheel).

A small C++ harness, compiled at bench time against the wheel's headers and libraries (≈ 30–60 s),
loads ``bem_predictor.pt`` with ``torch::jit::load`` and the AOTInductor package with one
``torch::inductor::AOTIModelPackageLoader`` per method, and times ``bem_mean`` and ``forward`` on
one query (B = 1, one thread, ``torch::NoGradGuard``) in ``rounds`` alternating rounds of
``per_round`` calls each (``std::chrono::steady_clock`` per call), so a change of background load
affects all four cases alike.  It prints each case's median and 99th percentile (µs) and each
artifact's outputs (``%.17g``) for the parity check against Python.
"""

from __future__ import annotations

import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import torch

from bemlearn.errors import EnvironmentProblem
from bemlearn.export.aoti import find_cxx

__all__ = ["CppTiming", "libtorch_command", "time_cpp_predictors", "HARNESS"]

HARNESS = r"""#include <ATen/Parallel.h>
#include <torch/csrc/inductor/aoti_package/model_package_loader.h>
#include <torch/script.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <string>
#include <vector>

using Fn = std::function<std::vector<torch::Tensor>(const torch::Tensor &)>;

int main(int argc, char **argv)
{
    // harness TS.pt AOTI.pt2 ROUNDS PER_ROUND x_1 ... x_n
    at::set_num_threads(1);
    torch::NoGradGuard no_grad;
    torch::jit::Module ts = torch::jit::load(argv[1]);
    torch::inductor::AOTIModelPackageLoader aoti_bem(argv[2], "bem_mean"), aoti_fwd(argv[2], "model");
    int rounds = std::atoi(argv[3]), per_round = std::atoi(argv[4]), n = argc - 5;
    std::vector<double> values(n);
    for (int i = 0; i < n; ++i) values[i] = std::atof(argv[5 + i]);
    torch::Tensor x = torch::from_blob(values.data(), {1, n}, torch::kFloat64).clone();
    auto ts_bem = ts.get_method("bem_mean");
    auto ts_fwd = ts.get_method("forward");
    std::vector<std::pair<std::string, Fn>> cases = {
        {"torchscript bem_mean", [&](const torch::Tensor &v) { return std::vector<torch::Tensor>{ts_bem({v}).toTensor()}; }},
        {"torchscript forward", [&](const torch::Tensor &v) {
             auto t = ts_fwd({v}).toTuple();
             return std::vector<torch::Tensor>{t->elements()[0].toTensor(), t->elements()[1].toTensor()};
         }},
        {"aoti bem_mean", [&](const torch::Tensor &v) { return aoti_bem.run({v}); }},
        {"aoti forward", [&](const torch::Tensor &v) { return aoti_fwd.run({v}); }},
    };
    std::vector<std::vector<double>> us(cases.size());
    for (auto &c : cases) {
        auto out = c.second(x);
        std::printf("value %s", c.first.c_str());
        for (auto &t : out) std::printf(" %.17g", t.item<double>());
        std::printf("\n");
        for (int r = 0; r < 200; ++r) c.second(x);
    }
    for (int r = 0; r < rounds; ++r)
        for (size_t c = 0; c < cases.size(); ++c)
            for (int i = 0; i < per_round; ++i) {
                auto t0 = std::chrono::steady_clock::now();
                cases[c].second(x);
                auto t1 = std::chrono::steady_clock::now();
                us[c].push_back(std::chrono::duration<double, std::micro>(t1 - t0).count());
            }
    for (size_t c = 0; c < cases.size(); ++c) {
        auto &v = us[c];
        std::sort(v.begin(), v.end());
        std::printf("time %s %.4f %.4f\n", cases[c].first.c_str(), v[v.size() / 2], v[(v.size() * 99) / 100]);
    }
    return 0;
}
"""


@dataclass(frozen=True)
class CppTiming:
    """The C++ harness's result: (median µs, p99 µs) per case, each case's outputs, and the build time (s)."""

    latencies: dict[str, tuple[float, float]]
    values: dict[str, list[float]]
    build_seconds: float


def libtorch_command(source: Path, out: Path) -> list[str]:
    """The compile-and-link command of one C++ file against the wheel's libtorch (include dirs
    ``torch/include`` and ``torch/include/torch/csrc/api/include``, ``-ltorch -ltorch_cpu -lc10``
    with an rpath, the wheel's ``_GLIBCXX_USE_CXX11_ABI``)."""
    cxx = find_cxx()
    if cxx is None:
        raise EnvironmentProblem("no C++ compiler (c++, g++ or clang++) on PATH")
    root = Path(torch.__file__).resolve().parent
    lib = root / "lib"
    return [cxx, "-std=c++17", "-O2", f"-D_GLIBCXX_USE_CXX11_ABI={int(torch.compiled_with_cxx11_abi())}",
            "-isystem", str(root / "include"), "-isystem", str(root / "include" / "torch" / "csrc" / "api" / "include"),
            str(source), "-o", str(out), f"-L{lib}", f"-Wl,-rpath,{lib}",
            "-Wl,--no-as-needed", "-ltorch", "-ltorch_cpu", "-lc10", "-Wl,--as-needed"]


def time_cpp_predictors(torchscript: Path, aoti: Path, x: list[float], *, rounds: int = 10, per_round: int = 1000) -> CppTiming:
    """Build the harness and time both artifacts on the query ``x`` (the 3m BEM inputs).

    Raises:
        EnvironmentProblem: no C++ compiler, or the build or the run failed (message with its output).
    """
    import time

    with tempfile.TemporaryDirectory(prefix="bemlearn-cpp-") as tmp:
        src, exe = Path(tmp) / "harness.cpp", Path(tmp) / "harness"
        src.write_text(HARNESS)
        t0 = time.perf_counter()
        done = subprocess.run(libtorch_command(src, exe), capture_output=True, text=True)
        build = time.perf_counter() - t0
        if done.returncode != 0:
            raise EnvironmentProblem(f"building the libtorch timing harness failed:\n{done.stderr[-3000:]}")
        run = subprocess.run([str(exe), str(torchscript), str(aoti), str(rounds), str(per_round), *map(repr, x)],
                             capture_output=True, text=True, timeout=1200)
        if run.returncode != 0:
            raise EnvironmentProblem(f"the libtorch timing harness failed:\n{run.stderr[-3000:]}")
    lat: dict[str, tuple[float, float]] = {}
    values: dict[str, list[float]] = {}
    for line in run.stdout.splitlines():
        kind, rest = line.split(" ", 1)
        words = rest.split()
        name = " ".join(words[:2])
        if kind == "time":
            lat[name] = (float(words[2]), float(words[3]))
        elif kind == "value":
            values[name] = [float(v) for v in words[2:]]
    return CppTiming(lat, values, build)
