"""The study's summary, "where each method wins": per (scene, engine) the winner (highest median
test PSNR), every method's median difference to uniform with a bootstrap 95% CI and a Mann-Whitney
p-value (Bonferroni over the methods compared with uniform in that cell), PSNR/SSIM/LPIPS, and the
coverage of the chosen views (share on the unseen half of the hemisphere; mean pairwise angle).

Written as OUT/study.md with figures under OUT/figures/, and by `write_results_doc` as a Markdown
page elsewhere (docs/results.md) with its figures copied beside it. Every number is computed from
the run folders; nothing is written by hand.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nerfaug.experiment.runfolder import read_selection
from nerfaug.jsonio import atomic_write_bytes
from nerfaug.metrics import HIGHER_IS_BETTER, METRIC_DECIMALS, METRIC_LABELS, METRICS
from nerfaug.plotting import new_figure, save_figure
from nerfaug.report.collect import ReportError, Results, collect_results
from nerfaug.report.document import (
    Block,
    Bullets,
    Figure,
    Heading,
    Paragraph,
    Table,
    number,
    p_value,
    slug,
    to_markdown,
)
from nerfaug.report.figures import method_colours, plot_boxplots
from nerfaug.report.pooled import plot_paired_differences, pooled_comparisons
from nerfaug.statistics import (
    bootstrap_median_difference,
    compare,
    summarise,
    view_coverage,
)

REFERENCE = "uniform"
OURS = "ours"
ALPHA = 0.05
BOOTSTRAP_SEED = 0


@dataclass
class MethodResult:
    """One method in one (scene, engine) cell.

    Attributes:
        values: metric -> one value per valid trial (trial order).
        vs_reference: metric -> the difference of medians to uniform with its CI and test
            (`bootstrap_median_difference` and `compare` merged); absent for uniform itself and
            where either side has no values.
        coverage: per trial, {"trial", "unseen_share", "spread_deg"} of the chosen views.
    """

    method: str
    values: dict[str, list[float]]
    vs_reference: dict[str, dict] = field(default_factory=dict)
    coverage: list[dict] = field(default_factory=list)

    def median(self, metric: str) -> float | None:
        return summarise(self.values[metric])["median"] if self.values.get(metric) else None

    def coverage_median(self, key: str) -> float | None:
        found = [c[key] for c in self.coverage if c[key] is not None and np.isfinite(c[key])]
        return float(np.median(found)) if found else None


@dataclass
class Cell:
    """One (scene, engine): its methods' results, the winner and what is missing."""

    scene: str
    engine: str
    methods: dict[str, MethodResult]
    n_comparisons: int
    planned: int
    missing: list[str]
    lpips_notes: list[str]

    @property
    def winner(self) -> str | None:
        medians = [(r.median("psnr"), m) for m, r in self.methods.items() if r.median("psnr") is not None]
        return max(medians, key=lambda x: x[0])[1] if medians else None

    @property
    def complete(self) -> bool:
        return not self.missing


@dataclass
class Study:
    root: Path
    plan: dict
    cells: list[Cell]
    not_run: dict[str, str]
    results: dict[str, Results]

    @property
    def methods(self) -> list[str]:
        """Every method with results in some cell, in the order the cells list them."""
        return list(dict.fromkeys(m for c in self.cells for m in c.methods))


def _coverage(results: Results, scene: str, method: str) -> list[dict]:
    found = []
    for run in results.runs_of(scene, method):
        selection = read_selection(run.folder)
        if selection is None or selection.chosen_poses is None:
            continue
        found.append({"trial": run.trial, **view_coverage(selection.chosen_poses, selection.train_poses)})
    return found


def compare_with_reference(x: list[float], y: list[float], metric: str, n_comparisons: int) -> dict:
    """median(x) - median(y) with its bootstrap CI, and the Mann-Whitney test (Bonferroni x
    n_comparisons) in the metric's direction."""
    test = compare(x, y, n_comparisons, higher_is_better=HIGHER_IS_BETTER[metric], alpha=ALPHA)
    return {
        **bootstrap_median_difference(x, y, seed=BOOTSTRAP_SEED),
        **{k: test[k] for k in ("p_value", "p_bonferroni", "significant", "better", "too_small", "n_comparisons")},
    }


def make_cell(results: Results, scene: str, engine: str, methods: list[str], trials: int) -> Cell:
    """The cell of `scene` in one engine's results; `methods` and `trials` are the study's plan."""
    present = [m for m in results.methods if results.values(scene, m, "psnr")]
    by_method = {
        m: MethodResult(
            m, {metric: results.values(scene, m, metric) for metric in METRICS}, coverage=_coverage(results, scene, m)
        )
        for m in present
    }
    compared = [m for m in present if m != REFERENCE]
    k = max(1, len(compared))
    reference = by_method.get(REFERENCE)
    for method in compared if reference is not None else []:
        for metric in METRICS:
            x, y = by_method[method].values[metric], reference.values[metric]
            if x and y:
                by_method[method].vs_reference[metric] = compare_with_reference(x, y, metric, k)
    missing = [
        f"{m}: {len(by_method[m].values['psnr']) if m in by_method else 0} of {trials} trials"
        for m in methods
        if (len(by_method[m].values["psnr"]) if m in by_method else 0) < trials
    ]
    lpips = sorted(
        {
            str(r.result.get("lpips_status", "unknown reason"))
            for r in results.runs_of(scene)
            if r.metric("lpips") is None
        }
    )
    return Cell(scene, engine, by_method, k, trials, missing, lpips)


def collect_study(root: Path) -> Study:
    """Read OUT/study.json and every engine's results folder into cells."""
    root = Path(root)
    path = root / "study.json"
    try:
        plan = json.loads(path.read_text())
    except (OSError, ValueError) as error:
        raise ReportError(f"{path}: not readable ({error}); run `nerfaug study --out {root}` first") from None
    engines = list(plan.get("engines", [])) + [e for e in plan.get("left_out", {}) if e not in plan.get("engines", [])]
    cells, not_run, found = [], dict(plan.get("left_out", {})), {}
    for engine in engines:
        folder = root / engine
        if not (folder / "sweep.json").is_file():
            not_run.setdefault(engine, "not run yet (no results folder)")
            continue
        results = found[engine] = collect_results(folder)
        not_run.pop(engine, None)
        for scene in plan.get("scenes", results.scenes):
            cells.append(
                make_cell(
                    results, scene, engine, list(plan.get("methods", results.methods)), int(plan.get("trials", 0))
                )
            )
    return Study(root, plan, cells, not_run, found)


# ----------------------------------------------------------------------------- text


def _difference(entry: dict | None, metric: str) -> str:
    if entry is None:
        return "n/a"
    d = METRIC_DECIMALS[metric]
    low, high, difference = (round(entry[k], d) + 0.0 for k in ("low", "high", "difference"))  # + 0.0: no "-0.00"
    ci = "" if np.isnan(low) else f" [{number(low, d)}, {number(high, d)}]"
    return f"{difference:+.{d}f}{ci}"


def _verdict(entry: dict | None) -> str:
    """Whether a method beats uniform on this metric, in words."""
    if entry is None:
        return "not compared"
    if entry["significant"]:
        return "**beats uniform**" if entry["better"] else "**worse than uniform**"
    return "no significant difference" + (" (n too small)" if entry["too_small"] else "")


def _ours_sentence(cell: Cell) -> str:
    ours = cell.methods.get(OURS)
    entry = ours.vs_reference.get("psnr") if ours else None
    where = f"{cell.scene}, {cell.engine}"
    if entry is None:
        return f"{where}: not compared (ours or uniform has no valid runs)."
    verb = (
        "beats uniform"
        if entry["significant"] and entry["better"]
        else "is worse than uniform"
        if entry["significant"]
        else "does not beat uniform"
    )
    return (
        f"{where}: ours {verb} (median PSNR {_difference(entry, 'psnr')} dB, p x {entry['n_comparisons']} = "
        f"{p_value(entry['p_bonferroni'])}{'' if entry['significant'] else ', not < 0.05'})"
        + ("" if cell.complete else "; incomplete cell")
        + "."
    )


def where_wins_table(study: Study) -> Table:
    rows = []
    for cell in study.cells:
        ns = [len(r.values["psnr"]) for r in cell.methods.values()]
        winner = cell.winner
        ours = cell.methods.get(OURS)
        entry = ours.vs_reference.get("psnr") if ours else None
        beating = [
            m for m, r in cell.methods.items() if (e := r.vs_reference.get("psnr")) and e["significant"] and e["better"]
        ]
        rows.append(
            [
                cell.scene,
                cell.engine,
                f"{min(ns)}-{max(ns)}" if ns and min(ns) != max(ns) else str(max(ns, default=0)),
                f"{winner} ({number(cell.methods[winner].median('psnr'), 2)} dB)" if winner else "n/a",
                _difference(entry, "psnr"),
                p_value(entry["p_bonferroni"]) if entry else "n/a",
                ", ".join(beating) or "none",
                "yes" if cell.complete else "**no**",
            ]
        )
    notes = [
        (
            "winner: the highest median test PSNR. ours - uniform: difference of median PSNR (dB) with a "
            "percentile bootstrap 95% CI. p x k: two-sided Mann-Whitney U, Bonferroni over the k methods "
            "compared with uniform in the cell. Significantly better than uniform: p x k < 0.05 and a higher "
            "median PSNR."
        )
    ]
    return Table(
        [
            "scene",
            "engine",
            "trials",
            "winner (median PSNR)",
            "ours - uniform PSNR [95% CI]",
            "p x k",
            "significantly better than uniform",
            "complete",
        ],
        rows,
        notes,
    )


def cell_tables(cell: Cell) -> list[Block]:
    metrics_rows, coverage_rows = [], []
    for method, result in cell.methods.items():
        row = [method, str(len(result.values["psnr"]))]
        for metric in METRICS:
            entry = result.vs_reference.get(metric)
            row += [
                number(result.median(metric), METRIC_DECIMALS[metric]),
                _difference(entry, metric),
                p_value(entry["p_bonferroni"]) if entry else "n/a",
            ]
        metrics_rows.append(row)
        shares = [c["unseen_share"] for c in result.coverage if c["unseen_share"] is not None]
        coverage_rows.append(
            [
                method,
                str(len(result.coverage)),
                number(result.coverage_median("unseen_share"), 2),
                (f"{number(min(shares), 2)}-{number(max(shares), 2)}" if shares else "n/a"),
                number(result.coverage_median("spread_deg"), 1),
                _verdict(result.vs_reference.get("psnr")),
            ]
        )
    headers = ["method", "n"]
    for metric in METRICS:
        label = METRIC_LABELS[metric]
        headers += [
            f"{label} {'↑' if HIGHER_IS_BETTER[metric] else '↓'} median",
            f"{label} - uniform [95% CI]",
            f"p x {cell.n_comparisons}",
        ]
    notes = [f"LPIPS n/a: {status}" for status in cell.lpips_notes]
    if cell.missing:
        notes.append("Incomplete: " + "; ".join(cell.missing) + ".")
    blocks: list[Block] = [Heading(f"{cell.scene}, engine {cell.engine}", 3), Table(headers, metrics_rows, notes)]
    blocks.append(
        Table(
            [
                "method",
                "trials",
                "unseen-half share (median)",
                "range over trials",
                "spread: mean pairwise angle (deg, median)",
                "PSNR vs uniform",
            ],
            coverage_rows,
        )
    )
    return blocks


def _header(study: Study) -> list[Block]:
    plan, config = study.plan, study.plan.get("config", {})
    host = plan.get("machine", {})
    commands = plan.get("commands") or [plan.get("command", [])]
    command = "; ".join(f"`{' '.join(c)}`" for c in commands if c) or "n/a"
    items = [
        f"command{'s (one per sitting)' if len(commands) > 1 else ''}: {command}",
        f"study last started: {plan.get('written', 'n/a')}",
        (
            f"machine: {host.get('platform', '?')}, {host.get('cpu_count', '?')} CPUs, torch {host.get('torch', '?')}, "
            f"device {config.get('device', '?')}"
        ),
        f"engines run: {', '.join(plan.get('engines', [])) or 'none'}",
        f"scenes: {', '.join(plan.get('scenes', []))}; methods: {', '.join(plan.get('methods', []))}",
        f"trials per (scene, engine, method): {plan.get('trials', '?')} "
        f"(trial k uses seed {config.get('seed', 0)} + k)",
        (
            f"protocol: {config.get('n_initial', '?')} initial views, {config.get('n_new', '?')} added at step "
            f"{config.get('add_at_step', '?')}, {config.get('steps', '?')} steps, {config.get('resolution', '?')} px, "
            f"pool {config.get('pool', '?')}, {config.get('n_test', '?')} test views"
        ),
    ]
    return [Bullets(items)]


def _ours_section(study: Study) -> list[Block]:
    counts = {}
    for cell in study.cells:
        for method, result in cell.methods.items():
            entry = result.vs_reference.get("psnr")
            if entry and entry["significant"] and entry["better"]:
                counts.setdefault(method, set()).add(cell.scene)
    lines = [_ours_sentence(cell) for cell in study.cells]
    best = max(counts.items(), key=lambda kv: len(kv[1]), default=None)
    if best is None:
        verdict = "No method beats uniform with p < 0.05 (after the Bonferroni correction) on any cell."
    else:
        verdict = (
            "Methods that beat uniform with p < 0.05 on median PSNR, by scenes: "
            + "; ".join(f"{m}: {', '.join(sorted(s))}" for m, s in sorted(counts.items()))
            + "."
        )
    return [Heading("Does ours beat uniform?"), Bullets(lines or ["No cell has results yet."]), Paragraph(verdict)]


def _pooled_section(study: Study, figures: dict) -> list[Block]:
    cells = [(study.results[c.engine], c.scene) for c in study.cells]
    pooled = pooled_comparisons(cells, study.methods, REFERENCE, ALPHA, BOOTSTRAP_SEED)
    if not pooled:
        return []
    rows = []
    for method, by_metric in pooled.items():
        counted = next(iter(by_metric.values()))  # pooled_comparisons keeps only metrics with pairs
        row = [method, f"{counted['n_pairs']} ({counted['cells']})"]
        for metric in METRICS:
            entry = by_metric.get(metric)
            row += [
                _difference(entry, metric),
                f"{entry['wins']}/{entry['ties']}/{entry['losses']}" if entry else "n/a",
                p_value(entry["p_bonferroni"]) if entry else "n/a",
            ]
        rows.append(row)
    k = len(pooled)
    headers = ["method", "pairs (cells)"]
    for metric in METRICS:
        label = METRIC_LABELS[metric]
        headers += [f"{label} - uniform, paired [95% CI]", f"{label} wins/ties/losses", f"p x {k}"]
    text = (
        "A secondary analysis, added after the first cells had been seen, so read it as exploratory: the "
        "issue's aim is judged on the per-cell test above. Trial k of every method in a cell uses the same "
        "seed, so it starts from the same initial views and the same NeRF up to the step where views are "
        "added; each pair (method, uniform) differs only in the selection. Pooling the pairs of every cell "
        "asks whether a method beats uniform on average over the scenes and engines run. Difference: the "
        "median of the paired differences, with a percentile bootstrap 95% CI (pairs resampled together, "
        f"seed {BOOTSTRAP_SEED}). p: two-sided Wilcoxon signed-rank test, Bonferroni x{k}. Wins: pairs where "
        "the method is better than uniform in the metric's direction."
    )
    blocks: list[Block] = [Heading("Pooled over cells, paired by trial (secondary)"), Paragraph(text)]
    blocks.append(Table(headers, rows))
    if (path := figures.get(("paired", "", ""))) is not None:
        blocks.append(Figure(path, "PSNR of each method minus uniform's on the same trial; one dot per pair."))
    return blocks


def _incomplete_section(study: Study) -> list[Block]:
    items = [f"engine {engine}: {why}" for engine, why in study.not_run.items()]
    items += [f"{c.scene}, {c.engine}: " + "; ".join(c.missing) for c in study.cells if c.missing]
    return [
        Heading("Incomplete cells"),
        Bullets(items) if items else Paragraph("None: every planned cell is complete."),
    ]


# ----------------------------------------------------------------------------- figures


def plot_coverage(study: Study, engine: str, path: Path) -> Path | None:
    """Per scene: each method's unseen-half share (top) and spread (bottom) over trials."""
    cells = [c for c in study.cells if c.engine == engine and c.methods]
    if not cells:
        return None
    methods = list(dict.fromkeys(m for c in cells for m in c.methods))
    colours = method_colours(methods)
    figure = new_figure(max(5.0, 0.6 * len(methods)) * len(cells), 6.4)
    axes = figure.subplots(2, len(cells), squeeze=False)
    jitter = np.random.default_rng(0)
    for column, cell in enumerate(cells):
        for row, (key, label) in enumerate(
            (("unseen_share", "share of chosen views on the unseen half"), ("spread_deg", "mean pairwise angle (deg)"))
        ):
            ax = axes[row, column]
            for i, method in enumerate(methods):
                result = cell.methods.get(method)
                values = [
                    c[key] for c in (result.coverage if result else []) if c[key] is not None and np.isfinite(c[key])
                ]
                if values:
                    ax.scatter(
                        i + jitter.uniform(-0.12, 0.12, len(values)),
                        values,
                        s=16,
                        color=colours[method],
                        edgecolor="black",
                        linewidth=0.4,
                        zorder=3,
                    )
                    ax.plot([i - 0.3, i + 0.3], [np.median(values)] * 2, color="black", linewidth=1.5)
            if key == "unseen_share":
                ax.axhline(0.5, color="0.5", linestyle="--", linewidth=1)
                ax.set_ylim(-0.05, 1.05)
                ax.set_title(f"{cell.scene}", fontsize=10)
            ax.set_xticks(
                range(len(methods)), methods if row == 1 else [""] * len(methods), rotation=30, ha="right", fontsize=8
            )
            ax.set_ylabel(label if column == 0 else "", fontsize=9)
            ax.grid(axis="y", alpha=0.3)
    figure.suptitle(
        f"Coverage of the chosen views, engine {engine} (bar: median; dashed: a uniform pool's 0.5)", fontsize=11
    )
    return save_figure(figure, path)


def study_blocks(study: Study, figures: dict) -> list[Block]:
    blocks: list[Block] = [Heading("nerfaug study: where each method wins", 1)] + _header(study)
    blocks += [Heading("Where each method wins"), where_wins_table(study)]
    blocks += _ours_section(study) + _pooled_section(study, figures) + _incomplete_section(study)
    blocks.append(Heading("Per scene and engine"))
    blocks.append(
        Paragraph(
            "Medians over trials of each trial's mean over the test views. Differences are to uniform's median, "
            "with a percentile bootstrap 95% CI (scipy.stats.bootstrap, 9999 resamples, each sample resampled on "
            f"its own, seed {BOOTSTRAP_SEED}). Coverage: the share of a run's chosen views whose azimuth lies on "
            "the half of the hemisphere opposite to the initial views (centred on the initial views' mean "
            "azimuth), and the mean angle between the chosen views' directions from the centre."
        )
    )
    for cell in study.cells:
        blocks += cell_tables(cell)
        if (path := figures.get(("box", cell.engine, cell.scene))) is not None:
            blocks.append(
                Figure(
                    path, f"{cell.scene}, engine {cell.engine}: PSNR, SSIM and LPIPS per method; each dot is one trial."
                )
            )
    coverage = [(e, p) for (kind, e, _), p in figures.items() if kind == "coverage"]
    if coverage:
        blocks.append(Heading("Coverage of the chosen views"))
        blocks += [
            Figure(p, f"Engine {e}: unseen-half share and spread of each run's chosen views.") for e, p in coverage
        ]
    return blocks


def make_study_figures(study: Study) -> dict:
    folder, figures = study.root / "figures", {}
    for cell in study.cells:
        results = study.results[cell.engine]
        path = folder / f"boxplots_{slug(cell.engine)}_{slug(cell.scene)}.png"
        if plot_boxplots(results, cell.scene, path, f"{cell.scene}, engine {cell.engine}: test metrics over trials"):
            figures[("box", cell.engine, cell.scene)] = path
    for engine in dict.fromkeys(c.engine for c in study.cells):
        path = plot_coverage(study, engine, folder / f"coverage_{slug(engine)}.png")
        if path is not None:
            figures[("coverage", engine, "")] = path
    cells = [(study.results[c.engine], c.scene, f"{c.scene}, {c.engine}") for c in study.cells]
    if (path := plot_paired_differences(cells, study.methods, REFERENCE, folder / "paired_psnr.png")) is not None:
        figures[("paired", "", "")] = path
    return figures


def write_study(root: Path) -> list[Path]:
    """Write OUT/study.md and its figures from OUT/study.json and the engines' results folders.
    Returns study.md, then the figures."""
    study = collect_study(root)
    figures = make_study_figures(study)
    path = study.root / "study.md"
    atomic_write_bytes(path, to_markdown(study_blocks(study, figures), study.root).encode())
    return [path, *figures.values()]


READING_START, READING_END = "<!-- reading: written by hand, kept when the page is regenerated -->", "<!-- /reading -->"


def kept_reading(path: Path) -> str | None:
    """The hand-written reading of the numbers in an earlier version of the page at `path`: the
    text between `READING_START` and `READING_END`, markers included; None if there is none."""
    try:
        text = Path(path).read_text()
    except OSError:
        return None
    start, end = text.find(READING_START), text.find(READING_END)
    return text[start : end + len(READING_END)] if 0 <= start < end else None


def write_results_doc(root: Path, path: Path = Path("docs/results.md")) -> Path:
    """Write the study's summary as a Markdown page at `path` (e.g. docs/results.md), its figures
    copied into a folder beside it (`<stem>/`), with how it was made (command, date, machine).
    A hand-written reading of the numbers, between `READING_START` and `READING_END` in the
    page, is kept (after the header) when the page is regenerated."""
    from datetime import UTC, datetime

    study = collect_study(root)
    figures = make_study_figures(study)
    path = Path(path)
    folder = path.parent / path.stem
    copied = {}
    for key, figure in figures.items():
        target = folder / figure.name
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(figure, target)
        copied[key] = target
    blocks = study_blocks(study, copied)
    blocks[0] = Heading("Results: where each selection method wins", 1)
    blocks.insert(
        1,
        Paragraph(
            f"Generated from `{Path(root)}` on {datetime.now(UTC):%Y-%m-%d %H:%M UTC} by "
            f"`nerfaug study --out {Path(root)} --summary-only --results-doc {path}`; every number below is "
            "computed from the run folders."
        ),
    )
    markdown = to_markdown(blocks, path.parent)
    reading = kept_reading(path)
    if reading is not None:  # after the header's first two blocks (title, provenance)
        head, _, rest = markdown.partition("\n## ")
        markdown = f"{head.rstrip()}\n\n{reading}\n\n## {rest}" if rest else f"{markdown.rstrip()}\n\n{reading}\n"
    atomic_write_bytes(path, markdown.encode())
    return path


__all__ = ["Cell", "MethodResult", "Study", "collect_study", "make_cell", "write_results_doc", "write_study"]
