"""Build bem_predict.cpp against the libtorch inside the installed torch wheel.

    python examples/cpp_libtorch/build.py [OUT]      # default OUT: examples/cpp_libtorch/bem_predict

Uses the wheel's include dirs (torch/include, torch/include/torch/csrc/api/include), its lib dir
(torch/lib: -ltorch -ltorch_cpu -lc10, with an rpath so no LD_LIBRARY_PATH is needed) and the
C++ ABI the wheel was built with (torch._C._GLIBCXX_USE_CXX11_ABI).
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent


def command(out: Path) -> list[str]:
    import torch

    root = Path(torch.__file__).resolve().parent
    cxx = shutil.which("c++") or shutil.which("g++") or shutil.which("clang++")
    if cxx is None:
        raise RuntimeError("no C++ compiler (c++, g++ or clang++) on PATH")
    lib = root / "lib"
    return [cxx, "-std=c++17", "-O2", f"-D_GLIBCXX_USE_CXX11_ABI={int(torch._C._GLIBCXX_USE_CXX11_ABI)}",
            "-isystem", str(root / "include"), "-isystem", str(root / "include" / "torch" / "csrc" / "api" / "include"),
            str(HERE / "bem_predict.cpp"), "-o", str(out), f"-L{lib}", f"-Wl,-rpath,{lib}",
            "-Wl,--no-as-needed", "-ltorch", "-ltorch_cpu", "-lc10", "-Wl,--as-needed"]


def build(out: Path = HERE / "bem_predict") -> Path:
    cmd = command(out)
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{res.stderr[-4000:]}")
    return out


if __name__ == "__main__":
    print(build(Path(sys.argv[1]) if len(sys.argv) > 1 else HERE / "bem_predict"))
