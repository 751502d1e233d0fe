"""The report's learning curves: test PSNR against views in the model for runs in rounds, their
area per run, median and IQR per method, and a figure."""

from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import trapezoid

from nerfaug.report.collect import Results, Run
from nerfaug.report.document import Figure, Table
from nerfaug.report.learning_curve import curve_area, learning_curve_section, plot_learning_curves, run_curve


def rounds_result(psnrs: list[float], start_views: int = 4) -> dict:
    """A result.json of a run of len(psnrs) - 1 rounds of one view: psnrs[0] before the first round."""
    rounds = [
        {"round": r, "step": 100 * r, "views": start_views + r, "metrics": {"psnr": p}}
        for r, p in enumerate(psnrs[1:], 1)
    ]
    start = {"step": 100, "views": start_views, "metrics": {"psnr": psnrs[0]}}
    return {"metrics": {"psnr": psnrs[-1]}, "timing": {}, "rounds": rounds, "before_rounds": start}


def results_of(curves: dict[str, list[list[float]]], root: Path) -> Results:
    runs = [
        Run("lego", method, trial, root / method / str(trial), rounds_result(psnrs))
        for method, trials in curves.items()
        for trial, psnrs in enumerate(trials)
    ]
    one_round = Run("lego", "uniform", 9, root, {"metrics": {"psnr": 20.0}, "timing": {}, "chosen": [1]})
    return Results(root, {"config": {}}, runs + [one_round], [], [], ["lego"], list(curves))


def test_a_runs_curve_and_its_area_by_the_trapezoidal_rule():
    result = rounds_result([18.0, 19.5, 21.0, 20.5])
    curve = run_curve(Run("lego", "ours", 0, Path("."), result))
    assert curve == [(4, 18.0), (5, 19.5), (6, 21.0), (7, 20.5)]
    assert curve_area(curve) == pytest.approx(trapezoid([18.0, 19.5, 21.0, 20.5], [4, 5, 6, 7]))
    # A run of one round has no curve.
    assert run_curve(Run("lego", "ours", 0, Path("."), {"metrics": {"psnr": 20.0}, "timing": {}})) is None


def test_the_section_tabulates_each_methods_area_and_draws_the_curves(tmp_path):
    curves = {
        "uniform": [[18.0, 18.5, 19.0], [18.0, 19.0, 19.5], [18.0, 18.0, 18.5]],
        "furthest": [[18.0, 20.0, 21.0], [18.0, 20.5, 21.5], [18.0, 19.5, 20.0]],
    }
    results = results_of(curves, tmp_path)
    figure = plot_learning_curves(results, tmp_path / "curves.png")
    assert figure is not None and figure.read_bytes().startswith(b"\x89PNG")
    blocks = learning_curve_section(results, figure)
    assert any(isinstance(b, Figure) for b in blocks)
    (table,) = [b for b in blocks if isinstance(b, Table)]
    rows = {row[0]: row for row in table.rows}
    for method, trials in curves.items():
        areas = [trapezoid(p, [4, 5, 6]) for p in trials]
        q1, median, q3 = np.percentile(areas, [25, 50, 75])
        assert rows[method][1] == "3"  # the run of one round is left out
        assert rows[method][2] == f"{median:.1f} [{q1:.1f}, {q3:.1f}]"
        assert rows[method][-1] == f"{np.median([p[-1] for p in trials]):.2f}"
    assert table.headers[-3:] == ["PSNR at 4 views", "PSNR at 5 views", "PSNR at 6 views"]


def test_no_runs_in_rounds_no_section(tmp_path):
    results = results_of({}, tmp_path)
    assert plot_learning_curves(results, tmp_path / "curves.png") is None
    assert learning_curve_section(results, None) == []
