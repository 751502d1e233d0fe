"""The report of a results folder: median/IQR tables with Mann-Whitney U tests, the paper's
ablation tables and figures, run times and the runs left out, as `report.md` and a self-contained
`report.html` (figures embedded as data URIs), with the figures as PNGs under `figures/`.

Rooms: `collect` (reading the results folder), `document` (blocks, Markdown, HTML, number
formats), `figures` (the PNGs), `sections` (what the report says), `view_uncertainty` (a test
view's error and uncertainty images, AUSE), `learning_curve` (runs in rounds: test PSNR against
views), `study` (the multi-engine study's summary).

Only runs whose result.json is valid for the sweep's fingerprint (`store.read_result`) are
aggregated; every other run folder is listed with the reason, never silently counted.
"""

from __future__ import annotations

from pathlib import Path

from nerfaug import runfiles
from nerfaug.experiment.layout import ResultsFolder
from nerfaug.report.collect import (
    NotAggregated,
    ReportError,
    Results,
    Run,
    collect_results,
    why_not_valid,
)
from nerfaug.report.document import Block, to_html, to_markdown
from nerfaug.report.figures import Figures, figure_folder, history_series, make_figures
from nerfaug.report.learning_curve import learning_curve_section, plot_learning_curves
from nerfaug.report.sections import (
    PaperTables,
    figure_sections,
    header_section,
    problems_section,
    scene_section,
    summary_section,
    table_i_section,
    table_ii_section,
    timing_section,
    verdict_section,
)
from nerfaug.report.view_uncertainty import view_uncertainty_section


def build_report(
    results: Results, figures: Figures, paper: PaperTables, learning_curves: Path | None = None
) -> list[Block]:
    """The report's blocks; `learning_curves`: the figure of the runs' learning curves, if drawn."""
    blocks = header_section(results)
    blocks = blocks[:1] + verdict_section(results) + blocks[1:] + summary_section(results)
    for scene in results.scenes:
        blocks += scene_section(results, scene, figures.boxplots.get(scene))
    blocks += learning_curve_section(results, learning_curves)
    blocks += table_i_section(results, paper) + table_ii_section(results, paper)
    blocks += figure_sections(results, figures) + view_uncertainty_section(results, figures.view_uncertainty)
    blocks += timing_section(results, paper) + problems_section(results)
    return blocks


def write_report(results_dir: Path, paper: PaperTables) -> list[Path]:
    """Write `report.md`, a self-contained `report.html` and the figures (`figures/*.png`) for a
    results folder written by `nerfaug run`.

    Args:
        results_dir: the folder holding sweep.json and runs/<scene>/<method>/trial_<k>/.
        paper: the paper's ablation tables' rows and its protocol's image side
            (`nerfaug.cli.run_work.paper_tables()` gives the method registry's).

    Returns:
        The paths written: report.md, report.html, then the figures.

    Raises:
        ReportError: no readable sweep.json in `results_dir`.
    """
    results = collect_results(results_dir)
    root = results.root
    markdown, page = ResultsFolder(root).report
    for name in (markdown.name, page.name):  # refused before any figure is drawn, as figures/ is
        runfiles.path_in(root, name)
    figures = make_figures(results)
    curves = plot_learning_curves(results, figure_folder(root) / "learning_curves.png")
    blocks = build_report(results, figures, paper, curves)
    runfiles.write_text(root, markdown.name, to_markdown(blocks, root))
    runfiles.write_text(root, page.name, to_html(blocks, f"nerfaug report: {root.name}"))
    return [markdown, page] + figures.paths() + ([curves] if curves else [])


__all__ = [
    "NotAggregated",
    "PaperTables",
    "ReportError",
    "Results",
    "Run",
    "build_report",
    "collect_results",
    "history_series",
    "why_not_valid",
    "write_report",
]
