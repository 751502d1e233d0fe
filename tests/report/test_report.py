"""The report of a results folder, built from a fake folder with the exact layout protocol.py writes
and known numbers: medians, exclusion of invalid runs, LPIPS n/a, a self-contained HTML page."""

import re

import imageio.v3 as iio
import numpy as np
import pytest
import torch

from nerfaug.cli.run_work import paper_tables
from nerfaug.experiment.config import PROTOCOL_PRESETS
from nerfaug.experiment.runfolder import (
    FILES,
    read_selection,
    write_config,
    write_error,
    write_history,
    write_metrics,
    write_progress,
    write_selection,
    write_view_uncertainty,
)
from nerfaug.experiment.store import RunKey, run_fingerprint, write_result
from nerfaug.experiment.sweep import sweep_record
from nerfaug.hemisphere import angles_from_pose, half_hemisphere_poses, sample_uniform_poses
from nerfaug.jsonio import atomic_write_json
from nerfaug.report import ReportError, collect_results, history_series, write_report
from nerfaug.uncertainty.sparsification import ause, mean_pool

METHODS = ("ours", "uniform", "entropy")
# PSNR per (scene, method): three trials each. Hand-computed (numpy linear quartiles):
#   lego ours [20, 21, 23]: median 21, q1 20.5, q3 22, IQR 1.5.
#   lego uniform [12, 15, 14]: median 14, IQR 1.5. lego entropy [16, 19, 17.5]: median 17.5, IQR 1.5.
#   chair ours [25.5, 24, 26]: median 25.5, q1 24.75, q3 25.75, IQR 1.0.
PSNR = {
    ("lego", "ours"): [20.0, 21.0, 23.0],
    ("lego", "uniform"): [12.0, 15.0, 14.0],
    ("lego", "entropy"): [16.0, 19.0, 17.5],
    ("chair", "ours"): [25.5, 24.0, 26.0],
    ("chair", "uniform"): [18.0, 19.5, 21.0],
    ("chair", "entropy"): [22.0, 22.5, 23.5],
}
SSIM = {"ours": [0.84, 0.83, 0.86], "uniform": [0.70, 0.72, 0.71], "entropy": [0.80, 0.79, 0.81]}
LPIPS = {"ours": [0.13, 0.14, 0.12], "uniform": [0.31, 0.30, 0.29], "entropy": [0.16, 0.18, 0.17]}
LPIPS_MISSING = "LPIPS unavailable: AlexNet weights not found at /nowhere/alexnet.pth"


def config():
    return PROTOCOL_PRESETS.choose("tiny").replace(scenes=("lego", "chair"), methods=METHODS, trials=3)


# A test view's squared error (8x8, rising to the right and down), and each method's uncertainty
# images of it: ours ranks the error exactly (AUSE 0); uniform is constant (a random ranking) with
# FisherRF reversed; entropy saved no FisherRF image.
VIEW_ERROR = np.add.outer(np.arange(8.0), np.arange(8.0)) / 100


def view_arrays(method: str) -> dict:
    arrays = {"render": np.full((8, 8, 3), 0.5), "error": VIEW_ERROR}
    if method == "ours":
        return {**arrays, "entropy": 3 * VIEW_ERROR, "fisher": mean_pool(VIEW_ERROR, 4, 4) + 1e-6}
    if method == "uniform":
        return {**arrays, "entropy": np.ones((8, 8)), "fisher": -mean_pool(VIEW_ERROR, 4, 4) + 1}
    return {**arrays, "entropy": VIEW_ERROR[::-1, ::-1]}


def write_run(root, record, scene, method, trial, psnr, lpips_available=True, generator=None, view=False):
    """One run folder as `protocol.run_trial` writes it, through the same run-folder contract;
    result.json last. With `view`, the first test view's arrays (`view_arrays`), which runs made
    before they were saved lack."""
    folder = RunKey(scene, method, trial).folder(root)
    if view:
        write_view_uncertainty(folder, view_arrays(method))
    candidates = sample_uniform_poses(12, torch.Generator().manual_seed(len(scene)))  # the scene's pool
    initial = half_hemisphere_poses(3)
    chosen = [int(i) for i in torch.randperm(12, generator=generator)[:2]]
    scores = torch.rand(12, generator=generator)
    selection = {"method": method, "indices": chosen, "scores": scores.tolist(), "components": {}}
    write_selection(folder, selection, [f"r_{i}" for i in chosen], candidates, initial)
    renders = folder / FILES.renders
    renders.mkdir(parents=True)
    shade = 40 * trial + 10 * len(method)
    render = np.full((8, 8, 3), shade, dtype=np.uint8)
    iio.imwrite(renders / "0000_render.png", render)
    iio.imwrite(renders / "0000_render_vs_gt.png", np.concatenate([render, np.full_like(render, 200)], axis=1))
    ssim = SSIM.get(method, SSIM["ours"])[trial % 3]
    lpips = LPIPS.get(method, LPIPS["ours"])[trial % 3] if lpips_available else None
    write_metrics(
        folder,
        {
            "per_view": [{"index": 0, "name": "r_0", "psnr": psnr, "ssim": ssim, "lpips": lpips}],
            "mean": {"psnr": psnr, "ssim": ssim, "lpips": lpips},
            "lpips_status": "available: test" if lpips_available else LPIPS_MISSING,
        },
    )
    losses = lambda step: {"rgb": 0.9 / step, "distortion": 0.01 / step, "interlevel": 0.001 / step}  # noqa: E731
    write_history(
        folder,
        [{"step": step, "loss": 1.0 / step, "psnr": psnr * step / 60, "losses": losses(step)} for step in range(1, 61)],
    )
    write_config(folder, record["config"], {})
    write_result(
        folder,
        {
            "scene": scene,
            "method": method,
            "trial": trial,
            "seed": trial,
            "fingerprint": run_fingerprint(record["fingerprint"], record["methods"].get(method)),
            "code_version": "test",
            "metrics": {"psnr": psnr, "ssim": ssim, "lpips": lpips},
            "lpips_status": "available: test" if lpips_available else LPIPS_MISSING,
            "chosen": chosen,
            "timing": {
                "setup": 1.0,
                "train_before": 2.0,
                "selection": 3.0 + trial,
                "oracle": 0.1,
                "train_after": 30.0,
                "evaluation": 4.0,
                "total": 40.1 + trial,
            },
            "host": "testhost",
            "torch": torch.__version__,
        },
    )
    return folder


def make_results(root, corrupt=True):
    """2 scenes x 3 methods x 3 trials with the known numbers (no LPIPS on chair; the test view's
    uncertainty arrays on lego only, chair's runs are as older runs wrote them); with `corrupt`,
    also a truncated result.json (PSNR 99.99) and a result of another configuration (PSNR 77.77)."""
    record = sweep_record(config(), ["nerfaug", "run", "--preset", "tiny"])
    atomic_write_json(root / "sweep.json", record)
    generator = torch.Generator().manual_seed(0)
    for (scene, method), values in PSNR.items():
        for trial, psnr in enumerate(values):
            lego = scene == "lego"
            write_run(root, record, scene, method, trial, psnr, lpips_available=lego, generator=generator, view=lego)
    if corrupt:
        truncated = write_run(root, record, "lego", "ours", 3, 99.99, generator=generator) / "result.json"
        truncated.write_text(truncated.read_text()[:60])
        other = {**record, "fingerprint": "0123456789abcdef"}
        write_run(root, other, "lego", "uniform", 4, 77.77, generator=generator)
    return root


def table_rows(markdown: str, heading: str) -> dict[str, list[str]]:
    """The first table after `heading`, as method -> cells."""
    section = markdown.split(heading, 1)[1]
    lines = [line for line in section.split("\n\n", 2)[1].splitlines() if line.startswith("|")]
    return {cells[0]: cells for cells in ([c.strip() for c in line.strip("|").split("|")] for line in lines[2:])}


def first_table_after(markdown: str, heading: str) -> dict[str, list[str]]:
    """The first table after `heading` (past figures and text), as first cell -> cells."""
    lines = markdown.split(heading, 1)[1].splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("|"))
    end = next((i for i in range(start, len(lines)) if not lines[i].startswith("|")), len(lines))
    rows = [[c.strip() for c in line.strip("|").split("|")] for line in lines[start + 2 : end]]
    return {cells[0]: cells for cells in rows}


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    root = make_results(tmp_path_factory.mktemp("results"))
    paths = write_report(root, paper_tables())
    return root, paths, (root / "report.md").read_text(), (root / "report.html").read_text()


def test_files_are_written(report):
    root, paths, _, _ = report
    assert paths[:2] == [root / "report.md", root / "report.html"]
    names = {p.name for p in paths[2:]}
    for scene in ("lego", "chair"):
        assert {f"fig4_boxplots_{scene}.png", f"fig1_uncertainty_{scene}.png", f"fig3_renders_{scene}.png"} <= names
    assert "training_curves.png" in names
    for path in paths:
        assert path.is_file() and path.stat().st_size > 0
    for path in paths[2:]:
        assert iio.imread(path).ndim == 3  # a real PNG


def test_the_uncertainty_of_a_test_view_with_each_methods_ause(report):
    root, paths, markdown, _ = report
    assert root / "figures" / "view_uncertainty_lego.png" in paths
    assert not (root / "figures" / "view_uncertainty_chair.png").exists()  # its runs saved no arrays
    section = markdown.split("## Uncertainty of a test view", 1)[1]
    assert "view_uncertainty_lego.png" in section and "### chair" not in section.split("## ", 1)[0]
    rows = first_table_after(section, "### lego")
    # method, runs, AUSE entropy median (IQR), AUSE FisherRF median (IQR); every trial alike: IQR 0.
    assert rows["ours"] == ["ours", "3 of 3", "0.000 (0.000)", "0.000 (0.000)"]
    constant = ause(np.ones((8, 8)), VIEW_ERROR)
    reversed_fisher = ause(-mean_pool(VIEW_ERROR, 4, 4), mean_pool(VIEW_ERROR, 4, 4))
    assert constant > 0.05 and reversed_fisher > 0.05
    assert rows["uniform"][2:] == [f"{constant:.3f} (0.000)", f"{reversed_fisher:.3f} (0.000)"]
    assert rows["entropy"][3] == "n/a"  # no FisherRF image saved
    # A figure of the same view, one row per method, with its AUSE in the panel titles.
    image = iio.imread(root / "figures" / "view_uncertainty_lego.png")
    assert image.shape[0] > 500 and image.shape[1] > 1000


def test_a_report_of_runs_without_view_arrays_has_no_such_section(tmp_path):
    record = sweep_record(config().replace(scenes=("lego",), methods=("ours", "uniform"), trials=1), ["nerfaug"])
    atomic_write_json(tmp_path / "sweep.json", record)
    for method in ("ours", "uniform"):
        write_run(tmp_path, record, "lego", method, 0, 20.0, generator=torch.Generator().manual_seed(2))
    paths = write_report(tmp_path, paper_tables())
    assert "Uncertainty of a test view" not in (tmp_path / "report.md").read_text()
    assert not any("view_uncertainty" in p.name for p in paths)
    # One run of two with the arrays: the other is counted as left out.
    write_view_uncertainty(RunKey("lego", "ours", 0).folder(tmp_path), view_arrays("ours"))
    write_report(tmp_path, paper_tables())
    section = (tmp_path / "report.md").read_text().split("## Uncertainty of a test view", 1)[1]
    assert "1 run(s) without the arrays" in section and first_table_after(section, "### lego")["ours"][1] == "1 of 1"


def strip_bold(cell: str) -> str:
    return cell.replace("**", "")


def test_medians_and_iqrs_match_hand_computed_values(report):
    _, _, markdown, _ = report
    lego = table_rows(markdown, "## Scene: lego")
    # method, n, PSNR median, PSNR IQR, SSIM median, SSIM IQR, LPIPS median, LPIPS IQR
    assert [strip_bold(c) for c in lego["ours"][1:4]] == ["3", "21.00", "1.50"]
    assert [strip_bold(c) for c in lego["uniform"][1:4]] == ["3", "14.00", "1.50"]
    assert [strip_bold(c) for c in lego["entropy"][1:4]] == ["3", "17.50", "1.50"]
    assert strip_bold(lego["ours"][4]) == "0.8400"  # SSIM median of [0.84, 0.83, 0.86]
    assert strip_bold(lego["ours"][6]) == "0.1300"  # LPIPS median of [0.13, 0.14, 0.12]
    chair = table_rows(markdown, "## Scene: chair")
    assert [strip_bold(c) for c in chair["ours"][1:4]] == ["3", "25.50", "1.00"]
    # differences in dB with their CI (not a percent of a dB value): 21 - 14 = +7 dB
    assert re.search(r"\+7\.00 dB \(95% CI [+-]\d+\.\d\d to [+-]\d+\.\d\d\) median PSNR vs uniform", markdown)
    assert "% median PSNR" not in markdown
    # spreads as both IQRs with their n: equal ranges read as equal, never "x% smaller"
    assert "1.50 (n=3) vs 1.50 (n=3)" in markdown and "smaller" not in markdown
    assert "under the machine's load" in markdown  # timings say what they measured


def test_invalid_runs_are_listed_and_left_out(report):
    root, _, markdown, html = report
    not_aggregated = markdown.split("## Runs not aggregated", 1)[1]
    assert "runs/lego/ours/trial_003" in not_aggregated and "truncated" in not_aggregated
    assert "runs/lego/uniform/trial_004" in not_aggregated and "another configuration" in not_aggregated
    for text in (markdown, html):
        assert "99.99" not in text and "77.77" not in text
    results = collect_results(root)
    assert len(results.runs) == 18
    assert {r.trial for r in results.runs} == {0, 1, 2}


def test_lpips_unavailable_is_shown_as_na(report):
    _, _, markdown, _ = report
    chair = table_rows(markdown, "## Scene: chair")
    assert chair["ours"][6] == "n/a" and chair["uniform"][6] == "n/a"
    assert LPIPS_MISSING in markdown.split("## Scene: chair", 1)[1]


def test_comparison_reports_bonferroni_and_small_n(report):
    _, _, markdown, _ = report
    assert "Bonferroni x2" in markdown  # two baselines
    # 3 vs 3 trials: the smallest two-sided p is 0.1, so nothing can be significant.
    assert "n too small" in markdown and "**yes**" not in markdown


def test_html_is_self_contained(report):
    _, _, _, html = report
    assert 'src="http' not in html and "href=" not in html and "<link" not in html and "<script" not in html
    sources = re.findall(r'<img [^>]*src="([^"]*)"', html)
    assert len(sources) >= 7  # 2 box plots, 2 maps, 2 render grids, the training curves
    assert all(s.startswith("data:image/png;base64,") for s in sources)
    assert "<style>" in html


def test_header_names_what_was_run(report):
    _, _, markdown, _ = report
    assert "nerfaug run --preset tiny" in markdown
    assert "scenes: lego, chair" in markdown and "engine preset: test" in markdown
    assert "testhost" in markdown


def test_table_ii_appears_only_with_its_methods(tmp_path):
    record = sweep_record(config().replace(scenes=("lego",), methods=("ours", "ours-nbv"), trials=2), ["nerfaug"])
    atomic_write_json(tmp_path / "sweep.json", record)
    generator = torch.Generator().manual_seed(1)
    for method, values in (("ours", [20.0, 22.0]), ("ours-nbv", [13.0, 15.0])):
        for trial, psnr in enumerate(values):
            write_run(tmp_path, record, "lego", method, trial, psnr, generator=generator)
    write_report(tmp_path, paper_tables())
    markdown = (tmp_path / "report.md").read_text()
    assert "NBV vs sampling (Table II)" in markdown and "Table I)" not in markdown
    assert "ours vs ours-nbv" in markdown and "+7.00 dB (95% CI" in markdown  # 21 vs 14


def test_missing_planned_runs_and_no_valid_runs(tmp_path):
    atomic_write_json(tmp_path / "sweep.json", sweep_record(config(), ["nerfaug"]))
    paths = write_report(tmp_path, paper_tables())
    markdown = (tmp_path / "report.md").read_text()
    assert "never run: 18" in markdown and "lego/ours/trial 0" in markdown
    assert paths == [tmp_path / "report.md", tmp_path / "report.html"]


def test_not_a_results_folder(tmp_path):
    with pytest.raises(ReportError, match="sweep.json"):
        write_report(tmp_path, paper_tables())


@pytest.mark.parametrize(
    "history",
    [
        [{"step": s, "loss": 1.0, "psnr": float(s)} for s in (1, 2, 3)],
        {"step": [1, 2, 3], "psnr": [1.0, 2.0, 3.0]},
    ],
)
def test_history_series_reads_both_layouts(history):
    key, steps, values = history_series(history)
    assert key == "psnr" and steps.tolist() == [1, 2, 3] and values.tolist() == [1.0, 2.0, 3.0]


def test_failed_run_shows_its_recorded_error(tmp_path):
    from nerfaug.report import why_not_valid

    folder = tmp_path / "run"
    write_error(folder, "TrainingDiverged: loss is nan at step 12")
    assert why_not_valid(folder, "abc") == "failed: TrainingDiverged: loss is nan at step 12"


def test_interrupted_run_shows_its_last_progress(tmp_path):
    from nerfaug.report import why_not_valid

    write_progress(tmp_path, 150)
    assert (
        why_not_valid(tmp_path, "abc")
        == "no result.json (interrupted, failed or still running, last progress at step 150)"
    )


def test_selection_round_trips_through_the_contract(tmp_path):
    candidates = sample_uniform_poses(5, torch.Generator().manual_seed(3))
    initial = half_hemisphere_poses(2)
    write_selection(
        tmp_path,
        {"method": "ours", "indices": [4, 1], "scores": [0.1, 0.2, 0.3, 0.4, 0.5]},
        ["r_4", "r_1"],
        candidates,
        initial,
    )
    record = read_selection(tmp_path)
    assert record.method == "ours" and record.indices == [4, 1]
    assert np.allclose(record.chosen_poses, candidates[[4, 1]].numpy(), atol=1e-6)
    assert np.allclose(record.train_poses, initial.numpy(), atol=1e-6)
    azimuth, _, _ = angles_from_pose(candidates)
    assert np.allclose(record.raw["candidate_azimuth"], azimuth.numpy())
    (tmp_path / FILES.selection).write_text('{"scores": [1, 2]}')  # lacks the poses: not drawable
    assert read_selection(tmp_path) is None


def test_the_view_figure_shows_the_tables_ause_units_on_its_bars_and_fisherrf_at_the_views_size(tmp_path):
    from nerfaug.report import collect_results
    from nerfaug.report.view_uncertainty import ause_table, view_uncertainty_figure

    root = make_results(tmp_path, corrupt=False)
    for trial in (1, 2):  # uniform's later trials rank the error exactly: its median differs from trial 0's
        folder = RunKey("lego", "uniform", trial).folder(root)
        write_view_uncertainty(folder, {**view_arrays("uniform"), "entropy": 3 * VIEW_ERROR})
    results = collect_results(root)
    rows = {row[0]: row for row in ause_table(results, "lego").rows}
    figure = view_uncertainty_figure(results, "lego")
    panels, bars = figure.axes[:12], [ax.get_ylabel() for ax in figure.axes[12:]]  # 3 rows of 4, then the bars
    uniform = panels[4:8]
    assert rows["uniform"][2].startswith("0.000 (")  # the median of 0, 0 and the constant image's AUSE
    assert uniform[2].get_title() == "ray entropy\nAUSE 0.000 (median of 3 runs)"
    assert uniform[3].get_title().endswith(f"AUSE {rows['uniform'][3].split()[0]} (median of 3 runs)")
    fisher, error = uniform[3].images[0], uniform[1].images[0]
    assert fisher.get_array().shape == error.get_array().shape == (8, 8)  # computed at 4x4, drawn at 8x8
    assert (
        len(bars) == 8
        and all(bars)
        and any("bits" in b for b in bars)
        and any("no unit" in b and "log scale" in b for b in bars)
    )


def test_the_training_curves_say_they_are_the_training_batchs_psnr_and_mark_the_added_views(report):
    from nerfaug.report import collect_results
    from nerfaug.report.figures import training_curves_figure

    root, _, _, _ = report
    figure = training_curves_figure(collect_results(root))
    ax = figure.axes[0]
    assert ax.get_ylabel() == "training-batch PSNR (dB)"
    assert any(t.get_text().strip() == "views added" for t in ax.texts)
    assert len(ax.lines) == len(METHODS) + 1  # a curve per method and the add step
    assert "not held-out views" in figure._suptitle.get_text()


def test_the_training_curves_draw_each_named_loss(report):
    """A collapse is read loss by loss: a second row draws rgb, distortion and interlevel apart."""
    from nerfaug.report import collect_results
    from nerfaug.report.figures import training_curves_figure

    root, _, _, _ = report
    figure = training_curves_figure(collect_results(root))
    below = figure.axes[len(figure.axes) // 2]
    assert [line.get_label() for line in below.lines[:3]] == ["rgb", "distortion", "interlevel"]
    assert below.get_yscale() == "log" and "loss" in below.get_ylabel()


def test_the_report_opens_with_one_plain_verdict_naming_the_engine(report):
    """The first thing under the title, in the Markdown and the HTML: the engine, and ours against
    each baseline on each scene, computed (lego: ours 21 vs uniform 14 and entropy 17.5; chair:
    25.5 vs 19.5 and 22.5); three trials a side cannot support a difference after the correction."""
    _, _, markdown, html = report
    first = markdown.split("\n\n")[1]
    engine = config().engine
    assert first.startswith(f"**Verdict** (engine {engine}): on lego, ours vs uniform: +7.00 dB median PSNR, 95% CI")
    for said in ("ours vs entropy: +3.50 dB", "on chair, ours vs uniform: +6.00 dB", "ours vs entropy: +3.00 dB"):
        assert said in first
    assert first.count("not supported: too few trials to support any difference (3 vs 3)") == 4
    assert "\n" not in first and "significant" not in first
    body = html.split("<body", 1)[1]
    assert body.index("Verdict") < body.index("<table") and f"(engine {engine})" in body


def test_the_verdict_says_supported_or_not_and_the_smallest_difference_the_run_could_see():
    from nerfaug.report.sections import _comparison_words
    from nerfaug.statistics import bootstrap_median_difference

    rng = np.random.default_rng(0)
    baseline = list(20 + rng.normal(0, 1, 10))
    close, far = [v + 0.1 for v in baseline[::-1]], [v + 5 for v in baseline]
    d = bootstrap_median_difference(close, baseline)
    line = _comparison_words(close, baseline, "ours", "uniform", 3)
    assert line.startswith(f"ours vs uniform: {d['difference']:+.2f} dB median PSNR, 95% CI {d['low']:+.2f} to ")
    assert ", not supported (p x 3 = " in line
    assert f"differences under about {(d['high'] - d['low']) / 2:.2f} dB, half the CI's width" in line
    assert ", better: supported (p x 3 = " in _comparison_words(far, baseline, "ours", "uniform", 3)
    assert ", worse: supported (p = " in _comparison_words(baseline, far, "ours", "uniform", 1)


def test_the_loss_panel_pools_every_method_and_wears_no_methods_colour(report):
    from matplotlib.colors import to_rgb

    from nerfaug.report import collect_results
    from nerfaug.report.figures import method_colours, training_curves_figure

    root, _, _, _ = report
    results = collect_results(root)
    figure = training_curves_figure(results)
    below = figure.axes[len(figure.axes) // 2]
    methods = {tuple(round(c, 3) for c in to_rgb(colour)) for colour in method_colours(results.methods).values()}
    drawn = {tuple(round(c, 3) for c in to_rgb(line.get_color())) for line in below.lines[:3]}
    assert not drawn & methods, "a loss curve is drawn in a method's colour"
    assert "every method's runs pooled" in below.get_legend().get_title().get_text()
