"""The small things a new user hits first: a closed pipe, the C header's band text, the report's slope
signs, baseline and ranges, rounded config values, honest progress totals, help for every option, no
internal issue numbers in user-facing text, a current timings table."""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from bemlearn.cli.main import CLOSED_PIPE_STATUS, build_parser

ROOT = Path(__file__).resolve().parents[1]


# --- a closed pipe (`bemlearn config show X | head -1`) ---------------------------------------------------------------

@pytest.mark.parametrize("argv", [["config", "show", "configs/furuta.yaml"], ["examples"]])
def test_a_closed_stdout_ends_the_command_quietly(argv):
    """The reader is gone before the first byte (what `| head -1` becomes once head has its line): no
    traceback, no "internal error", the 128 + SIGPIPE status a shell shows for such a pipe."""
    r, w = os.pipe()
    os.close(r)
    try:
        done = subprocess.run([sys.executable, "-m", "bemlearn", *argv], cwd=ROOT, stdout=w, stderr=subprocess.PIPE,
                              text=True, timeout=120)
    finally:
        os.close(w)
    assert done.returncode == CLOSED_PIPE_STATUS == 141, done.stderr
    assert "Traceback" not in done.stderr and "internal error" not in done.stderr and "Exception ignored" not in done.stderr
    assert done.stderr == ""


# --- the C header's band formula: one text, the one the code computes --------------------------------------------------

def test_the_c_header_states_the_band_formula_the_code_computes():
    from bemlearn.export.c_templates import HEADER, POSTERIOR, SOURCE
    from bemlearn.models.band import BAND_FORMULA

    assert BAND_FORMULA in HEADER.template
    assert "+ max(sum_i" in BAND_FORMULA  # the larger of the two terms, as band_extra_variance (torch.maximum) and the C code
    assert "max(sum_i g_i^2, sum_k eps_k^2)" in SOURCE.template and "g2 = gi > ge ? gi : ge;" in POSTERIOR.template
    assert "+ (1/K) sum_k" not in HEADER.template  # the old text summed the two terms


def test_band_extra_variance_is_the_larger_term_not_the_sum():
    """The formula's text against the code: input-noise term and estimator term, both non-zero, give their max."""
    from bemlearn.models.band import band_extra_variance
    from bemlearn.models.input_noise import mean_gradient
    from bemlearn.models.predictor_state import PredictorState

    g = torch.Generator().manual_seed(0)
    n, d = 12, 5
    Z = torch.randn(n, d, generator=g, dtype=torch.float64)
    state = PredictorState(kind="exact", Z=Z, alpha=torch.randn(n, generator=g, dtype=torch.float64),
                           S=torch.eye(n, dtype=torch.float64) * 0.1, lengthscale=torch.ones(d, dtype=torch.float64),
                           outputscale=torch.tensor(1.0, dtype=torch.float64), noise=torch.tensor(1e-3, dtype=torch.float64),
                           x_mean=torch.zeros(d, dtype=torch.float64), x_std=torch.ones(d, dtype=torch.float64),
                           y_mean=torch.tensor(0.0, dtype=torch.float64), y_std=torch.tensor(1.0, dtype=torch.float64),
                           input_names=("qdd_a", "qd_a", "q_a", "qdd_u", "qd_u"), n_train=n,
                           input_std=torch.tensor([0.3, 0.2, 0.1, 0.0, 0.0], dtype=torch.float64),
                           estimator_delta=torch.randn(n, 2, generator=g, dtype=torch.float64) * 0.5)
    x = torch.randn(40, d, generator=g, dtype=torch.float64)
    var_in = ((mean_gradient(state, x) * state.input_std) ** 2).sum(-1)
    var_est = (state.kernel_row(x) @ state.estimator_delta).square().mean(-1)
    assert bool((var_in > 0).all() and (var_est > 0).all()) and bool(((var_in > var_est) != (var_in > var_est)[0]).any())
    torch.testing.assert_close(band_extra_variance(state, x, n_inputs=3), torch.maximum(var_in, var_est), rtol=1e-12, atol=0)


# --- the report: slope signs, the zero baseline, the data's ranges ------------------------------------------------------

def _resolution(slope: float, factor: float | None) -> dict:
    return {"spread": 0.01, "band_std": 0.002, "ratio": 5.0, "unit": "rad",
            "inputs": [{"input": "qdd_theta", "slope": slope, "amplitude": 16.0, "range": [-33.2, 32.9], "unit": "rad/s²",
                        "share": 0.1, "factor": factor}]}


def _typed(doc: dict):
    from bemlearn.pipeline.run_metrics import RunMetrics

    return RunMetrics.from_dict(doc)


class _Config:
    def __init__(self, signs):
        self.evaluate = type("E", (), {"slope_signs": signs})()


def test_the_report_says_when_a_slope_sign_looks_flipped():
    from bemlearn.pipeline.report import _data_only_lines

    text = "\n".join(_data_only_lines(_typed({"resolution": _resolution(+0.00765, 0.2)}), "rad", _Config({"qdd_theta": -1})))
    assert "qdd_theta: the sign looks flipped" in text and "0.00765" in text and "says negative" in text
    text = "\n".join(_data_only_lines(_typed({"resolution": _resolution(-0.02, 0.2)}), "rad", _Config({"qdd_theta": -1})))
    assert "flipped" not in text and "is negative, as the convention says" in text
    text = "\n".join(_data_only_lines(_typed({"resolution": _resolution(+0.00765, 3.0)}), "rad", _Config({"qdd_theta": -1})))
    assert "flipped" not in text and "cannot tell its sign" in text  # a slope inside the band: no claim either way
    assert "Sign convention" not in "\n".join(_data_only_lines(_typed({"resolution": _resolution(0.1, 0.2)}), "rad", _Config({})))


def test_the_report_gives_the_datas_range_as_the_slice_figure_marks_it():
    """One rule for "the data cover": the slices' quantiles, not ±1 std (the text said ±16 where the plot marked ±33)."""
    from bemlearn.pipeline.report import _data_only_lines

    text = "\n".join(_data_only_lines(_typed({"resolution": _resolution(-0.02, 0.2)}), "rad", _Config({})))
    assert "data cover -33.2 … 32.9 rad/s² (95 %)" in text and "±16" not in text


def test_the_zero_bem_is_labelled_the_expected_failure():
    from bemlearn.pipeline.report import _closed_loop_lines

    row = {"fell": False, "diverged": True, "duration_s": 60.0, "tracking_rmse": 0.3, "qu_max": 60.47, "u_max": 5.0,
           "real_time_factor": 10.0}
    from bemlearn.pipeline.run_metrics import DataInfo, LoopMetrics

    sim = {"predictor": LoopMetrics.from_dict({**row, "diverged": False, "qu_max": 0.1}), "zero": LoopMetrics.from_dict(row)}
    text = "\n".join(_closed_loop_lines(sim, DataInfo(input_units="V"), _typed({"unactuated": "alpha"}), "rad"))
    (zero_row,) = [line for line in text.splitlines() if line.startswith("| zero")]
    assert "zero (baseline)" in zero_row and "diverged" in zero_row and "expected to fail" in zero_row
    (pred_row,) = [line for line in text.splitlines() if line.startswith("| predictor")]
    assert "expected" not in pred_row and "baseline" not in pred_row
    assert "its failure is not a failure of the run" in text


# --- config show: rounded values ---------------------------------------------------------------------------------------

def test_config_show_prints_rounded_values():
    from bemlearn.pipeline.resolve import format_resolved, resolve_pipeline_config

    resolved = resolve_pipeline_config({"robot": "x.xml", "collect": {"fall_window": 0.1 + 0.2, "amplitude": [0.1 + 0.5, 0.7]}},
                                       derive=False)
    text = format_resolved(resolved)
    (fall,) = [line for line in text.splitlines() if line.startswith("collect.fall_window ")]
    (amp,) = [line for line in text.splitlines() if line.startswith("collect.amplitude ")]
    assert fall.split()[1] == "0.3" and amp.split()[1:3] == ["[0.6,", "0.7]"]
    assert "0.30000000000000004" not in text and "0.6000000000000001" not in text
    assert resolved.to_json_dict()["collect.fall_window"]["value"] == 0.1 + 0.2  # --json keeps the exact value


# --- progress bars: the total is what the option bounds -----------------------------------------------------------------

@pytest.mark.parametrize("optimizer", ["lbfgs", "adam"])
def test_the_fit_progress_total_is_max_iter(optimizer, capsys):
    from bemlearn.fitting.optimize import minimize

    p = torch.nn.Parameter(torch.tensor([3.0, -2.0], dtype=torch.float64))
    target = torch.tensor([1.0, 0.5], dtype=torch.float64)
    evals = minimize(lambda: ((p - target) ** 2 * torch.tensor([1.0, 30.0], dtype=torch.float64)).sum() + (p**4).sum() * 1e-3,
                     [p], optimizer=optimizer, max_iter=20, lr=1.0 if optimizer == "lbfgs" else 0.05, tol=0.0,
                     metrics_fn=dict, progress=True, desc="fit").steps
    err = capsys.readouterr().err
    totals = set(re.findall(r"\d+/(\d+)", err))
    assert totals == {"20"}, err[-500:]
    shown = max(int(n) for n in re.findall(r"(\d+)/20", err))
    assert shown <= 20 and (optimizer == "adam" or evals >= shown)


# --- help for every option; no pointer to a README that says nothing -----------------------------------------------------

def _actions(parser: argparse.ArgumentParser, path: tuple[str, ...] = ("bemlearn",)):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _actions(sub, (*path, name))
        elif not isinstance(action, (argparse._HelpAction, argparse._VersionAction)):
            yield " ".join(path), action


def test_every_option_and_argument_has_help():
    missing = [f"{cmd} {'/'.join(a.option_strings) or a.dest}" for cmd, a in _actions(build_parser())
               if not a.help or a.help == argparse.SUPPRESS]
    assert not missing, f"options without help: {missing}"


def test_help_texts_are_self_contained():
    """A help text may name a docs page, never "see README" (which may say nothing about it)."""
    bad = [f"{cmd} {'/'.join(a.option_strings) or a.dest}" for cmd, a in _actions(build_parser()) if "README" in (a.help or "")]
    assert not bad, bad
    (threads,) = [a for cmd, a in _actions(build_parser()) if cmd == "bemlearn train" and "--threads" in a.option_strings]
    assert "default 1" in threads.help and "docs/design.md" in threads.help


# --- no internal issue numbers where users read -------------------------------------------------------------------------

ISSUE = re.compile(r"\bissues? ?#?\d+|\bthe issue'?s?\b|(?<![\w.-])#\d+\b", re.IGNORECASE)


def _user_facing_texts() -> dict[str, str]:
    texts = {str(p.relative_to(ROOT)): p.read_text() for p in sorted((ROOT / "configs").rglob("*.yaml"))}
    texts |= {str(p.relative_to(ROOT)): p.read_text() for p in sorted((ROOT / "docs").glob("*.md"))}
    texts["README.md"] = (ROOT / "README.md").read_text()
    texts["CLI help"] = "\n".join(f"{cmd}: {a.help}" for cmd, a in _actions(build_parser()) if a.help)
    texts["CLI descriptions"] = "\n".join(p.description or "" for p in _parsers(build_parser()))
    texts["bemlearn/pipeline/report.py"] = (ROOT / "bemlearn" / "pipeline" / "report.py").read_text()
    return texts


def _parsers(parser):
    yield parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                yield from _parsers(sub)


def test_no_internal_issue_numbers_in_user_facing_text():
    texts = _user_facing_texts()
    assert len(texts) > 20
    hits = [f"{name}: {m.group(0)!r}" for name, text in texts.items() for m in ISSUE.finditer(text)]
    assert not hits, hits
    assert ISSUE.search("The example of issue 24") and ISSUE.search("see #15") and ISSUE.search("the issue's targets")
    assert not ISSUE.search("open report (gpytorch#2736)")  # an upstream project's tracker is a citation, not ours


# --- docs/timings.md: the suite row is current ---------------------------------------------------------------------------

@pytest.mark.slow
def test_the_timings_suite_row_counts_todays_tests():
    """The top table's suite row counts at least 90 % of the tests collected today (it said 1050 when there were 1396)."""
    row = next(line for line in (ROOT / "docs" / "timings.md").read_text().splitlines() if line.startswith("| `python -m pytest"))
    documented = int(re.search(r"(\d+) (?:tests|passed)", row).group(1))
    done = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q", "-n", "0", "-m", "not slow"], cwd=ROOT,
                          capture_output=True, text=True, timeout=600)
    collected = int(re.search(r"(\d+)(?:/\d+)? tests collected", done.stdout).group(1))
    assert documented >= 0.9 * collected, (documented, collected)


# --- Fig. 2's panel letters run without a gap ---------------------------------------------------------------------------

def test_fig2_panel_letters_have_no_gap():
    from types import SimpleNamespace

    import matplotlib.pyplot as plt
    import numpy as np

    from bemlearn.sim.figures import run_figure

    t = np.arange(0, 20.0, 0.01)
    res = SimpleNamespace(t=t, q=np.stack([np.sin(t), 0.01 * np.cos(t)], 1), qa_ref=np.sin(t)[:, None], qu_e=0.01 * np.cos(t),
                          u=np.zeros((t.size, 1)), metrics={"bem_source": "model"})
    for lemma, letters in ((None, "abc"), ({"t": np.linspace(0, 2, 50), "delta_gamma": np.zeros(50), "hdot": np.zeros(50)}, "abcd")):
        fig = run_figure(res, model_bem=0.01 * np.cos(t), lemma=lemma)
        assert [a.get_title()[:3] for a in fig.axes] == [f"({c})" for c in letters]
        plt.close(fig)
