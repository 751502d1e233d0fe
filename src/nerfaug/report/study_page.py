"""The study's page, "where each method wins": which method to use per regime, the methods, the
per-cell paired tests, the per-regime seed-level tests, the planned hypotheses' verdicts, each
cell's metrics and coverage, and the figures. Generated from the study's table alone
(`nerfaug.report.study_table`): as OUT/study.md with figures under OUT/figures/, and by
`write_results_doc` as a page elsewhere (docs/results.md) with its figures beside it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from nerfaug import runfiles
from nerfaug.experiment.layout import StudyFolder
from nerfaug.experiment.schedule import schedule_words
from nerfaug.jsonio import atomic_write_bytes
from nerfaug.metrics import HIGHER_IS_BETTER, METRIC_DECIMALS, METRIC_LABELS, METRICS
from nerfaug.plotting import new_figure, save_figure
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
from nerfaug.report.learning_curve import study_curve_blocks, study_curve_figures
from nerfaug.report.pooled import plot_paired_differences
from nerfaug.report.rounds_verdicts import OneShotArm
from nerfaug.report.study import ALPHA, BOOTSTRAP_SEED, OURS, REFERENCE, Cell, Study, collect_study
from nerfaug.report.study_hypotheses import hypotheses_blocks
from nerfaug.report.study_verdicts import floor_text, verdict_line


def _difference(entry: dict | None, metric: str) -> str:
    """ "+0.34 [0.11, 0.82]": the median paired difference with its CI, in the metric's unit."""
    if entry is None:
        return "n/a"
    d = METRIC_DECIMALS[metric]
    low, high, difference = (round(entry[k], d) + 0.0 for k in ("low", "high", "difference"))  # + 0.0: no "-0.00"
    ci = "" if np.isnan(low) else f" [{number(low, d)}, {number(high, d)}]"
    return f"{difference:+.{d}f}{ci}"


def _record(entry: dict | None) -> str:
    return f"{entry['wins']}/{entry['ties']}/{entry['losses']}" if entry else "n/a"


def _verdict(entry: dict | None) -> str:
    if entry is None:
        return "not compared"
    if entry["significant"]:
        return "**better than uniform**" if entry["better"] else "**worse than uniform**"
    return "no significant difference"


def background(study: Study, engine: str) -> str:
    return str(study.plan.get("engine_settings", {}).get(engine, {}).get("background_mode", "?"))


# ----------------------------------------------------------------------------- sections


def _empty_runs(study: Study) -> str:
    """Which cells hold runs whose NeRF rendered background only (runs recorded before the check
    count as not empty)."""
    cells: dict[tuple[str, str], int] = {}
    for run in study.table["runs"]:
        if run.get("empty"):
            cells[(run["engine"], run["scene"])] = cells.get((run["engine"], run["scene"]), 0) + 1
    what = (
        "runs whose NeRF rendered its training views as background only (the health check; runs "
        "recorded before it are not checked)"
    )
    if not cells:
        return f"{what}: none flagged"
    listed = ", ".join(f"{engine}/{scene} {n}" for (engine, scene), n in sorted(cells.items()))
    return f"{what}: {sum(cells.values())} ({listed}); they stay in their cells"


def _header(study: Study) -> list[Block]:
    plan, config = study.plan, study.plan.get("config", {})
    host = plan.get("machine", {})
    commands = plan.get("commands") or [plan.get("command", [])]
    command = "; ".join(f"`{' '.join(c)}`" for c in commands if c) or "n/a"
    versions = sorted({r["code_version"] for r in study.table["runs"]})
    engine_versions = [
        f"{engine} {', '.join(found)}"
        for engine in study.engines
        if (
            found := sorted(
                {r.get("engine_version") or "reference" for r in study.table["runs"] if r["engine"] == engine}
            )
        )
    ]
    items = [
        f"command{'s (one per sitting)' if len(commands) > 1 else ''}: {command}",
        f"study last started: {plan.get('written', 'n/a')}",
        (
            f"machine: {host.get('platform', '?')}, {host.get('cpu_count', '?')} CPUs, torch {host.get('torch', '?')}, "
            f"device {config.get('device', '?')}"
        ),
        f"code versions of the runs: {', '.join(versions) or 'none'}",
        f"engines run: {', '.join(study.engines) or 'none'}",
        "engine versions (reference: today's engine, alone or in a batch; a cell never mixes two): "
        f"{'; '.join(engine_versions) or 'none'}",
        _empty_runs(study),
        f"scenes: {', '.join(plan.get('scenes', []))}; methods: {', '.join(plan.get('methods', []))}",
        f"trials per (scene, engine, method): {plan.get('trials', '?')} "
        f"(trial k uses seed {config.get('seed', 0)} + k)",
        (
            f"protocol: {schedule_words(config)}, {config.get('steps', '?')} steps, "
            f"{config.get('resolution', '?')} px, {_pool_text(study, config)}, {_test_views_text(study, config)}"
        ),
        f"runs in the table: {len(study.table['runs'])}",
    ]
    if filled := _uniform_fill_text(study):
        items.append(filled)
    return [Bullets(items)]


def _uniform_fill_text(study: Study) -> str:
    """Which runs' samplers found fewer positive scores than views to add (the model gave the
    candidates no information, e.g. a NeRF that renders nothing) and drew the rest uniformly;
    "" when none did."""
    filled: dict[tuple[str, str, str], list[int]] = {}
    for run in study.table["runs"]:
        if run.get("uniform_fill", 0):
            filled.setdefault((run["method"], run["scene"], run["engine"]), []).append(run["uniform_fill"])
    if not filled:
        return ""
    parts = [
        f"{method} on {scene}, {engine}: {len(views)} runs, {sum(views)} views"
        for (method, scene, engine), views in sorted(filled.items())
    ]
    return (
        f"runs whose method found fewer candidates with a positive score than views to add, and drew the "
        f"others uniformly: {sum(len(v) for v in filled.values())} ({'; '.join(parts)})"
    )


def _test_views_text(study: Study, config: dict) -> str:
    """The test views the runs were scored on, per scene where the table records them (a captured
    set keeps fewer than the protocol asks), e.g. "test views: 50 (cow, mic), 12 (dtu_scan24)"."""
    counts: dict[int, list[str]] = {}
    for name, scene in study.table.get("scenes", {}).items():
        if "test_views" in scene:
            counts.setdefault(len(scene["test_views"]), []).append(name)
    if not counts:
        return f"{config.get('n_test', '?')} test views"
    return "test views per scene: " + ", ".join(f"{n} ({', '.join(sorted(s))})" for n, s in sorted(counts.items()))


def _pool_text(study: Study, config: dict) -> str:
    """The candidate pool in words: the protocol's `pool` is the number of views rendered for a
    built-in scene; a dataset folder (a scene recorded with its `source`) offers its own views."""
    scenes = study.table.get("scenes", {})
    folders = [name for name, scene in scenes.items() if "source" in scene]
    own = "a dataset folder's pool: its train split (a captured set's: the views left after its test and initial views)"
    if folders and len(folders) == len(scenes):
        return own
    return f"pool {config.get('pool', '?')}" + (f"; {own}" if folders else "")


def _which_method(study: Study) -> list[Block]:
    """Per regime (engine): the best method by the seed-level mean paired PSNR gain, its evidence,
    and the methods significantly better or worse than uniform."""
    rows, lines = [], []
    for engine in study.engines:
        regime = study.regimes.get(engine, {})
        cells = [c for c in study.cells if c.engine == engine and c.scene not in study.held_back]
        if not regime:
            continue
        best, entry = max(regime.items(), key=lambda kv: kv[1]["difference"])
        better = [m for m, e in regime.items() if e["significant"] and e["better"]]
        worse = [m for m, e in regime.items() if e["significant"] and not e["better"]]
        not_yet = [
            scene
            for m in study.missing_cells
            if m.endswith(f", {engine}") and (scene := m.split(",")[0]) not in study.held_back
        ]
        complete = all(c.complete for c in cells) and not not_yet
        used = [c.scene for c in cells if c.complete] or [c.scene for c in cells]  # as the regime test
        partial = [c.scene for c in cells if not c.complete]
        rows.append(
            [
                engine,
                background(study, engine),
                ", ".join(used) + ("" if complete else " (incomplete)"),
                f"{best} ({entry['difference']:+.2f} dB)",
                f"{entry['wins']}/{entry['n_seeds']}",
                p_value(entry["p_bonferroni"]),
                ", ".join(better) or "none",
                ", ".join(worse) or "none",
            ]
        )
        per_scene = _per_scene_better(cells)
        if better:
            top = max(better, key=lambda m: regime[m]["difference"])
            lines.append(
                f"engine {engine} (background {background(study, engine)}): use **{top}**; it beats uniform by "
                f"{regime[top]['difference']:+.2f} dB on average over {regime[top]['n_cells']} scene(s), better on "
                f"{regime[top]['wins']} of {regime[top]['n_seeds']} seeds (p x {regime[top]['n_comparisons']} = "
                f"{p_value(regime[top]['p_bonferroni'])})."
            )
        else:
            lines.append(
                f"engine {engine} (background {background(study, engine)}): no method beats uniform across its scenes "
                f"(one value per seed, p x "
                f"{entry['n_comparisons']} < {ALPHA:g}); "
                + (
                    f"the largest mean gain is {best}'s, {entry['difference']:+.2f} dB "
                    f"({entry['wins']} of {entry['n_seeds']} seeds)."
                    if entry["difference"] > 0
                    else f"none gains on average (the closest is {best}, {entry['difference']:+.2f} dB, better on "
                    f"{entry['wins']} of {entry['n_seeds']} seeds)."
                )
            )
            lines[-1] += " " + floor_text(entry)
        if per_scene:
            lines[-1] += f" Per scene (the primary test), better than uniform: {per_scene}."
        if worse:
            lines[-1] += (
                " Worse than uniform: " + ", ".join(f"{m} ({regime[m]['difference']:+.2f} dB)" for m in worse) + "."
            )
        if not complete:
            why = [f"{', '.join(partial)} part-way"] if partial else []
            why += [f"{', '.join(not_yet)} not run yet"] if not_yet else []
            lines[-1] += f" A provisional answer: from {', '.join(used)} only ({'; '.join(why)})."
    if not rows:
        return [Heading("Which method to use"), Paragraph("No regime has paired results yet.")]
    note = (
        "Per engine (a regime), across its complete scenes: each seed's mean over the scenes of (method - uniform) "
        "test PSNR on the trials of that seed, then the exact sign-flip permutation test on those per-seed values, "
        "Bonferroni over the methods compared. gain: the mean over seeds (dB); seeds: seeds whose mean favours "
        "the method."
    )
    if study.held_back:
        note += (
            f" {', '.join(study.held_back)}: held back to replicate what the other scenes find; judged per scene "
            "(the table below), never part of this mean."
        )
    table = Table(
        [
            "engine",
            "background",
            "scenes",
            "largest mean gain over uniform",
            "seeds",
            "p x k",
            "significantly better",
            "significantly worse",
        ],
        rows,
        [note],
    )
    return [Heading("Which method to use"), Bullets(lines), table]


def _per_scene_better(cells) -> str:
    """The methods the per-cell test finds better than uniform, with their scenes (complete cells
    only), e.g. "furthest (chair), ours-batch-sharp (chair, lego)"; "" when none."""
    scenes: dict[str, list[str]] = {}
    for cell in cells:
        if cell.complete:
            for method in cell.significant(True):
                scenes.setdefault(method, []).append(cell.scene)
    return ", ".join(f"{m} ({', '.join(s)})" for m, s in sorted(scenes.items()))


def _methods_section(study: Study) -> list[Block]:
    records = study.table.get("methods", {})
    rows = [
        [m, records.get(m, {}).get("label", m), records.get(m, {}).get("description", "not a registered method")]
        for m in study.methods
    ]
    return [Heading("The methods"), Table(["name", "label", "what it computes"], rows)]


def where_wins_table(study: Study) -> Table:
    rows = []
    for cell in study.cells:
        ns = [len(r.trials) for r in cell.methods.values()]
        winner = cell.winner
        ours = cell.methods.get(OURS)
        entry = ours.vs_reference.get("psnr") if ours else None
        rows.append(
            [
                cell.scene,
                cell.engine,
                f"{min(ns)}-{max(ns)}" if ns and min(ns) != max(ns) else str(max(ns, default=0)),
                f"{winner} ({number(cell.methods[winner].median('psnr'), 2)} dB)" if winner else "n/a",
                _difference(entry, "psnr"),
                p_value(entry["p_bonferroni"]) if entry else "n/a",
                ", ".join(cell.significant(True)) or "none",
                ", ".join(cell.significant(False)) or "none",
                "yes" if cell.complete else "**no**",
            ]
        )
    notes = [
        "winner: the highest median test PSNR. ours - uniform: the median over seeds of the paired difference in "
        "PSNR (dB; trial k of both shares seed, initial views and the NeRF up to the add step), with a percentile "
        f"bootstrap 95% CI (pairs resampled together, seed {BOOTSTRAP_SEED}). p x k: two-sided Wilcoxon "
        "signed-rank test on the paired differences, Bonferroni over the k methods compared with uniform in the "
        f"cell; significant: p x k < {ALPHA:g}."
    ]
    headers = [
        "scene",
        "engine",
        "trials",
        "winner (median PSNR)",
        "ours - uniform, paired [95% CI]",
        "p x k",
        "significantly better than uniform",
        "significantly worse",
        "complete",
    ]
    return Table(headers, rows, notes)


def _regime_section(study: Study, figures: dict) -> list[Block]:
    blocks: list[Block] = [
        Heading("Across scenes, one value per seed (secondary)"),
        Paragraph(
            "Trial k of every cell shares its seed (hence uniform's picks and the NeRF's initialisation), so the "
            "cells' pairs are not independent units. Per engine, each seed's paired PSNR differences are averaged "
            "over the scenes whose cells are complete (over every cell while none is; a scene held back for "
            "replication never); the sign-flip test "
            "(exact, every sign pattern of the per-seed values) and the "
            "Wilcoxon signed-rank test on the same values are shown, each Bonferroni-corrected over the methods."
        ),
    ]
    for engine in study.engines:
        regime = study.regimes.get(engine, {})
        rows = [
            [
                method,
                f"{e['n_cells']} x {e['n_seeds']}",
                f"{e['difference']:+.2f}",
                f"{e['median']:+.2f}",
                f"{e['wins']}/{e['ties']}/{e['losses']}",
                p_value(e["p_bonferroni"]),
                p_value(min(1.0, e["p_wilcoxon"] * e["n_comparisons"])),
            ]
            for method, e in regime.items()
        ]
        if rows:
            blocks.append(Heading(f"engine {engine} (background {background(study, engine)})", 3))
            blocks.append(
                Table(
                    [
                        "method",
                        "scenes x seeds",
                        "mean gain (dB)",
                        "median seed gain (dB)",
                        "seeds won/tied/lost",
                        "p x k (sign-flip)",
                        "p x k (signed-rank)",
                    ],
                    rows,
                )
            )
    if (path := figures.get(("paired", "", ""))) is not None:
        blocks.append(Figure(path, "PSNR of each method minus uniform's on the same seed; one dot per pair."))
    return blocks


def _incomplete_section(study: Study) -> list[Block]:
    items = [f"engine {engine}: {why}" for engine, why in study.not_run.items()]
    items += [f"{cell}: not run yet" for cell in study.missing_cells]
    items += [f"{c.scene}, {c.engine}: " + "; ".join(c.missing) for c in study.cells if c.missing]
    return [
        Heading("Incomplete cells"),
        Bullets(items) if items else Paragraph("None: every planned cell is complete."),
    ]


def cell_tables(cell: Cell) -> list[Block]:
    metrics_rows, coverage_rows = [], []
    for method, result in cell.methods.items():
        row = [method, str(len(result.trials))]
        for metric in METRICS:
            entry = result.vs_reference.get(metric)
            row += [
                number(result.median(metric), METRIC_DECIMALS[metric]),
                _difference(entry, metric),
                _record(entry),
                p_value(entry["p_bonferroni"]) if entry else "n/a",
            ]
        metrics_rows.append(row)
        shares = [c["unseen_share"] for c in result.coverage if c["unseen_share"] is not None]
        coverage_rows.append(
            [
                method,
                str(len(result.coverage)),
                number(result.coverage_median("unseen_share"), 2),
                f"{number(min(shares), 2)}-{number(max(shares), 2)}" if shares else "n/a",
                number(result.coverage_median("spread_deg"), 1),
                _verdict(result.vs_reference.get("psnr")),
            ]
        )
    headers = ["method", "n"]
    for metric in METRICS:
        label = METRIC_LABELS[metric]
        headers += [
            f"{label} {'↑' if HIGHER_IS_BETTER[metric] else '↓'} median",
            f"{label} - uniform, paired [95% CI]",
            "won/tied/lost",
            f"p x {cell.n_comparisons}",
        ]
    notes = [f"LPIPS n/a: {status}" for status in cell.lpips_notes]
    if cell.missing:
        notes.append("Incomplete: " + "; ".join(cell.missing) + ".")
    coverage = Table(
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
    return [Heading(f"{cell.scene}, engine {cell.engine}", 3), Table(headers, metrics_rows, notes), coverage]


def study_blocks(study: Study, figures: dict, plan: str = "auto", one_shot: OneShotArm | None = None) -> list[Block]:
    """The page's blocks; `plan` chooses the planned hypotheses judged (`study_hypotheses.KINDS`),
    `one_shot` the study of rounds' one-shot arm kept in a table of its own."""
    blocks: list[Block] = [Heading("nerfaug study: where each method wins", 1), Paragraph(verdict_line(study))]
    blocks += _header(study)
    blocks += _which_method(study) + _methods_section(study)
    blocks += [Heading("Per scene and engine: the paired test"), where_wins_table(study)]
    blocks += _regime_section(study, figures) + hypotheses_blocks(study, plan, one_shot) + _incomplete_section(study)
    blocks += study_curve_blocks(study.results, {e: p for (kind, e, _), p in figures.items() if kind == "curves"})
    blocks.append(Heading("Per scene and engine"))
    blocks.append(
        Paragraph(
            "Medians over trials of each trial's mean over the test views. Differences to uniform are paired by "
            "seed: the median of the per-seed differences with a percentile bootstrap 95% CI (9999 resamples, "
            f"seed {BOOTSTRAP_SEED}); won/tied/lost counts the seeds; p: two-sided Wilcoxon signed-rank, "
            "Bonferroni over the methods compared. Coverage: the share of a run's chosen views whose azimuth lies "
            "on the half of the hemisphere opposite to the initial views (centred on the initial views' mean "
            "azimuth; for a scene whose cameras cover a wedge of azimuths, as DTU's, the part of the wedge outside "
            "the half its initial views were taken from), and the mean angle between the chosen views' directions "
            "from the centre."
        )
    )
    for cell in study.cells:
        blocks += cell_tables(cell)
        if (path := figures.get(("box", cell.engine, cell.scene))) is not None:
            caption = f"{cell.scene}, engine {cell.engine}: PSNR, SSIM and LPIPS per method; each dot is one trial."
            blocks.append(Figure(path, caption))
    coverage = [(e, p) for (kind, e, _), p in figures.items() if kind == "coverage"]
    if coverage:
        blocks.append(Heading("Coverage of the chosen views"))
        blocks += [
            Figure(p, f"Engine {e}: unseen-half share and spread of each run's chosen views.") for e, p in coverage
        ]
    return blocks


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
    panels = (("unseen_share", "share of chosen views on the unseen half"), ("spread_deg", "mean pairwise angle (deg)"))
    for column, cell in enumerate(cells):
        for row, (key, label) in enumerate(panels):
            ax = axes[row, column]
            for i, method in enumerate(methods):
                result = cell.methods.get(method)
                found = [c[key] for c in (result.coverage if result else [])]
                values = [v for v in found if v is not None and np.isfinite(v)]
                if values:
                    x = i + jitter.uniform(-0.12, 0.12, len(values))
                    ax.scatter(x, values, s=16, color=colours[method], edgecolor="black", linewidth=0.4, zorder=3)
                    ax.plot([i - 0.3, i + 0.3], [np.median(values)] * 2, color="black", linewidth=1.5)
            if key == "unseen_share":
                ax.axhline(0.5, color="0.5", linestyle="--", linewidth=1)
                ax.set_ylim(-0.05, 1.05)
                ax.set_title(f"{cell.scene}", fontsize=10)
            labels = methods if row == 1 else [""] * len(methods)
            ax.set_xticks(range(len(methods)), labels, rotation=30, ha="right", fontsize=8)
            ax.set_ylabel(label if column == 0 else "", fontsize=9)
            ax.grid(axis="y", alpha=0.3)
    figure.suptitle(
        f"Coverage of the chosen views, engine {engine} (bar: median; dashed: a uniform pool's 0.5)", fontsize=11
    )
    return save_figure(figure, path)


def make_study_figures(study: Study, folder: Path) -> dict:
    figures = {}
    for cell in study.cells:
        path = folder / f"boxplots_{slug(cell.engine)}_{slug(cell.scene)}.png"
        title = f"{cell.scene}, engine {cell.engine}: test metrics over trials"
        if plot_boxplots(study.results[cell.engine], cell.scene, path, title):
            figures[("box", cell.engine, cell.scene)] = path
    for engine in study.engines:
        path = plot_coverage(study, engine, folder / f"coverage_{slug(engine)}.png")
        if path is not None:
            figures[("coverage", engine, "")] = path
    cells = [(study.results[c.engine], c.scene, f"{c.scene}, {c.engine}") for c in study.cells]
    if (path := plot_paired_differences(cells, study.methods, REFERENCE, folder / "paired_psnr.png")) is not None:
        figures[("paired", "", "")] = path
    figures |= {("curves", e, ""): p for e, p in study_curve_figures(study.results, folder).items()}
    return figures


# ----------------------------------------------------------------------------- pages


def write_study(root: Path, table: dict, plan: str = "auto", one_shot: OneShotArm | None = None) -> list[Path]:
    """Write ROOT/study.md and its figures (ROOT/figures/) from the study's table, judging the
    hypotheses of `plan` (`study_hypotheses.KINDS`; `one_shot`: `study_blocks`). Returns study.md,
    then the figures."""
    study = collect_study(table)
    folder = StudyFolder(Path(root))
    # study.md and figures/ linked out of the study folder are refused (`PathRefused`) before
    # anything is drawn; the paths stay as shown, so the page links its figures relative to ROOT.
    path = runfiles.checked(folder.root, folder.summary.relative_to(folder.root))
    figures = make_study_figures(study, runfiles.checked(folder.root, folder.figures.relative_to(folder.root)))
    markdown = to_markdown(study_blocks(study, figures, plan, one_shot), folder.root)
    runfiles.write_text(folder.root, path.relative_to(folder.root), markdown)
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


def write_results_doc(
    table: dict,
    table_path: Path,
    path: Path = Path("docs/results.md"),
    plan: str = "auto",
    one_shot: OneShotArm | None = None,
) -> Path:
    """Write the study's page at `path` (e.g. docs/results.md) from its table (at `table_path`, named
    on the page; `one_shot`: `study_blocks`), with its figures in a folder beside it (`<stem>/`). A
    hand-written reading of the numbers, between `READING_START` and `READING_END`, is kept (after
    the header) when the page is regenerated."""
    from datetime import UTC, datetime

    study = collect_study(table)
    path = Path(path)
    folder = path.parent / path.stem
    figures = make_study_figures(study, folder)
    blocks = study_blocks(study, figures, plan, one_shot)
    blocks[0] = Heading("Results: where each selection method wins", 1)
    option, tables, it = "" if plan == "auto" else f" --hypotheses {plan}", f"table `{table_path}`", "it"
    if one_shot is not None:  # the study of rounds' one-shot arm, read from a table of its own
        option += f" --one-shot-table {one_shot.source}"
        tables, it = f"tables `{table_path}` and `{one_shot.source}`", "them"
    blocks.insert(
        2,
        Paragraph(
            f"Generated on {datetime.now(UTC):%Y-%m-%d %H:%M UTC} by `nerfaug study --summary-only --table "
            f"{table_path} --results-doc {path}{option}` from the per-run {tables} alone; every number below is "
            f"computed from {it}, and the same command re-derives this page."
        ),
    )
    markdown = to_markdown(blocks, path.parent)
    reading = kept_reading(path)
    if reading is not None:  # after the header's first blocks (title, verdict, provenance)
        head, _, rest = markdown.partition("\n## ")
        markdown = f"{head.rstrip()}\n\n{reading}\n\n## {rest}" if rest else f"{markdown.rstrip()}\n\n{reading}\n"
    atomic_write_bytes(path, markdown.encode())
    return path


__all__ = ["kept_reading", "study_blocks", "where_wins_table", "write_results_doc", "write_study"]
