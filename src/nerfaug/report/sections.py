"""The report's sections: the header (what was run), the summary, one section per scene (median
and IQR table, comparison of ours with each baseline), the paper's ablation tables (Tables I and
II), the figures, run times and the runs left out. Each returns a list of document blocks."""

from __future__ import annotations

import json
import math
import platform
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from nerfaug.experiment.schedule import schedule_words
from nerfaug.metrics import HIGHER_IS_BETTER, METRIC_DECIMALS, METRIC_LABELS, METRICS
from nerfaug.report.collect import Results, Run
from nerfaug.report.document import (
    Block,
    Bullets,
    Code,
    Figure,
    Heading,
    Paragraph,
    Table,
    bold_best,
    number,
    p_value,
    seconds,
)
from nerfaug.report.figures import Figures
from nerfaug.statistics import bootstrap_median_difference, compare, summarise, summary_table

TIMING_FIELDS = (
    "setup",
    "train_before",
    "selection",
    "oracle",
    "train_after",
    "curve",
    "evaluation",
    "view_uncertainty",
    "total",
)
# The paper's run times (Sec. IV), cited in the run-time section at `PaperTables.resolution`.
PAPER_MINUTES_PER_RUN = {"ours": 11, "others": 8}
PAPER_GPU = "one RTX 6000 Ada"


@dataclass(frozen=True)
class PaperTables:
    """What the report compares with the paper: the rows of its ablation tables and the image side
    of its protocol. The caller gives them (the method registry's families and the experiments'
    paper preset are their one source); the report only lays them out.

    Attributes:
        table_i: (row label, method) of Table I (the uncertainty terms), in the paper's order.
        table_ii: (family, variant, method) of Table II (NBV vs sampling), in the paper's order,
            each family's NBV variant first.
        resolution: the image side in pixels the paper's run times were measured at.
    """

    table_i: tuple[tuple[str, str], ...]
    table_ii: tuple[tuple[str, str, str], ...]
    resolution: int


def _lpips_notes(runs: list[Run]) -> list[str]:
    statuses = sorted({str(r.result.get("lpips_status", "unknown reason")) for r in runs if r.metric("lpips") is None})
    return [f"LPIPS n/a: {status}" for status in statuses]


def header_section(results: Results) -> list[Block]:
    config, sweep = results.config, results.sweep
    methods = ", ".join(_label(results, m) for m in config.get("methods", results.methods))
    planned = len(config.get("scenes", [])) * len(config.get("methods", [])) * int(config.get("trials", 0))
    hosts = sorted({str(r.result.get("host")) for r in results.runs if r.result.get("host")})
    versions = sweep.get("versions", {})
    command = sweep.get("command") or []
    blocks: list[Block] = [
        Heading(f"nerfaug report: {results.root.name}", 1),
        Bullets(
            [
                f"scenes: {', '.join(config.get('scenes', results.scenes))}",
                f"methods: {methods}",
                f"trials per scene and method: {config.get('trials', '?')} "
                f"(trial k uses seed {config.get('seed', 0)} + k)",
                (f"steps: {config.get('steps', '?')}; {schedule_words(config)}"),
                (
                    f"engine preset: {config.get('engine', '?')}; resolution: {config.get('resolution', '?')} px; "
                    f"test views: {config.get('n_test', '?')}; candidate pool: {config.get('pool', '?')}"
                ),
                (
                    f"runs aggregated: {len(results.runs)} of {planned} planned; not aggregated: "
                    f"{len(results.not_aggregated)}; never run: {len(results.missing)}"
                ),
                f"fingerprint: `{sweep.get('fingerprint')}`",
                (
                    f"report written {datetime.now(UTC):%Y-%m-%d %H:%M UTC} on {platform.node()}; "
                    f"runs made on: {', '.join(hosts) or 'n/a'}"
                ),
                "versions: " + ", ".join(f"{k} {v}" for k, v in versions.items()),
            ]
        ),
        Paragraph("Command:"),
        Code(" ".join(str(part) for part in command) if isinstance(command, list) else str(command)),
        Code(json.dumps(config, indent=2, default=str), summary="configuration (JSON)"),
    ]
    if results.not_aggregated or results.missing:
        blocks.append(
            Paragraph(
                f"**Warning:** {len(results.not_aggregated)} run folder(s) were not aggregated and "
                f'{len(results.missing)} planned run(s) never ran; see "Runs not aggregated" at the end.'
            )
        )
    return blocks


def _summary_rows(results: Results, scene: str) -> dict[str, dict[str, dict]]:
    """method -> metric -> summary_table row, for one scene."""
    records = [
        {"scene": r.scene, "method": r.method, "trial": r.trial, **{m: r.metric(m) for m in METRICS}}
        for r in results.runs_of(scene)
    ]
    rows: dict[str, dict[str, dict]] = {}
    for metric in METRICS:
        table = summary_table(
            records,
            metric,
            results.ours or "",
            results.baselines,
            n_comparisons=max(1, len(results.baselines)),
            higher_is_better=HIGHER_IS_BETTER[metric],
        )
        for row in table:
            rows.setdefault(row["method"], {})[metric] = row
    return rows


def _median_table(results: Results, scene: str, rows: dict[str, dict[str, dict]]) -> Table:
    methods = [m for m in results.methods if m in rows]
    headers = ["method", "n"]
    columns: list[list[str]] = [[_label(results, m) for m in methods], [str(rows[m]["psnr"]["n"]) for m in methods]]
    for metric in METRICS:
        arrow = "↑" if HIGHER_IS_BETTER[metric] else "↓"
        headers += [f"{METRIC_LABELS[metric]} {arrow} median", f"{METRIC_LABELS[metric]} IQR"]
        decimals = METRIC_DECIMALS[metric]
        medians = [rows[m][metric]["median"] for m in methods]
        iqrs = [rows[m][metric]["iqr"] for m in methods]
        columns.append(bold_best([number(v, decimals) for v in medians], medians, not HIGHER_IS_BETTER[metric]))
        columns.append(bold_best([number(v, decimals) for v in iqrs], iqrs, True))
    notes = ["Median and interquartile range (IQR) of each trial's mean over the test views; best per column in bold."]
    notes += _lpips_notes(results.runs_of(scene))
    return Table(headers, [list(row) for row in zip(*columns)], notes)


# A metric's unit where it has one: differences of PSNR are in dB (never a percent of a dB value).
UNITS = {"psnr": " dB"}


def median_difference(x, y, metric: str) -> str:
    """median(x) - median(y) in the metric's unit, with its bootstrap 95% CI, e.g.
    "+1.23 dB (95% CI +0.40 to +2.10)"; the CI is "n/a" when a side has fewer than 2 values."""
    d = bootstrap_median_difference(x, y)
    decimals, unit = METRIC_DECIMALS[metric], UNITS.get(metric, "")
    text = f"{d['difference']:+.{decimals}f}{unit}"
    if math.isnan(d["low"]):
        return f"{text} (95% CI n/a: fewer than 2 trials)"
    return f"{text} (95% CI {d['low']:+.{decimals}f} to {d['high']:+.{decimals}f})"


def spreads(x, y, metric: str) -> str:
    """Both sides' interquartile ranges with their n, e.g. "0.41 (n=5) vs 0.38 (n=5)"."""
    decimals = METRIC_DECIMALS[metric]
    return " vs ".join(f"{summarise(v)['iqr']:.{decimals}f} (n={len(v)})" for v in (x, y))


def _label(results: Results, method: str) -> str:
    """The method's name, marked when it is the one compared with the others (unless it says so)."""
    return f"{method} (ours)" if method == results.ours and method != "ours" else method


def _direction(row: dict, ours_row: dict) -> str:
    if row["median"] == ours_row["median"]:
        return "equal"
    return "better" if row["better"] else "worse"


def _significance(row: dict) -> str:
    if row["significant"]:
        return "**yes**"
    return "no (n too small)" if row["too_small"] else "no"


def _comparison_table(results: Results, scene: str, rows: dict[str, dict[str, dict]]) -> Table | None:
    k = max(1, len(results.baselines))
    body, notes = [], []
    for baseline in results.baselines:
        for metric in METRICS:
            row = rows.get(baseline, {}).get(metric)
            ours_row = rows.get(results.ours, {}).get(metric)
            if row is None or row["p_value"] is None:
                continue
            label, decimals = METRIC_LABELS[metric], METRIC_DECIMALS[metric]
            x, y = results.values(scene, results.ours, metric), results.values(scene, baseline, metric)
            body.append(
                [
                    baseline,
                    label,
                    f"{number(ours_row['median'], decimals)} vs {number(row['median'], decimals)}",
                    f"{median_difference(x, y, metric)} ({_direction(row, ours_row)})",
                    spreads(x, y, metric),
                    p_value(row["p_value"]),
                    p_value(row["p_bonferroni"]),
                    _significance(row),
                ]
            )
            if row["too_small"] and row["note"] not in notes:
                notes.append(row["note"])
    if not body:
        return None
    notes = [
        (
            f"Two-sided Mann-Whitney U test of ours against each baseline, Bonferroni correction x{k} "
            f"(the number of baselines); significant means p x {k} < 0.05."
        )
    ] + [f"n too small: {n}." for n in notes]
    headers = [
        "baseline",
        "metric",
        "median (ours vs baseline)",
        "difference of the medians (ours - baseline)",
        "IQR of ours vs baseline's",
        "p",
        f"p x {k} (Bonferroni)",
        "significant",
    ]
    return Table(headers, body, notes)


def scene_section(results: Results, scene: str, boxplots: Path | None) -> list[Block]:
    blocks: list[Block] = [Heading(f"Scene: {scene}")]
    rows = _summary_rows(results, scene)
    if not rows:
        return blocks + [Paragraph("No aggregated runs for this scene.")]
    blocks.append(_median_table(results, scene, rows))
    comparison = _comparison_table(results, scene, rows) if results.ours in rows else None
    if comparison is not None:
        blocks += [Paragraph(f"**{_label(results, results.ours)}** against each baseline on {scene}:"), comparison]
    elif results.ours not in rows:
        blocks.append(Paragraph(f"No aggregated runs of {_label(results, results.ours)} on {scene}: no comparison."))
    if boxplots is not None:
        caption = f"Fig. 4 ({scene}): PSNR, SSIM and LPIPS per method over trials; each dot is one trial."
        blocks.append(Figure(boxplots, caption))
    return blocks


def _comparison_words(x, y, ours: str, baseline: str, n_comparisons: int) -> str:
    """ours against one baseline in plain words, computed: "ours vs uniform: +0.30 dB median
    PSNR, 95% CI -0.47 to +0.67, not supported (p x 3 = 0.41; differences under about 0.57 dB,
    half the CI's width, are beyond this run)"."""
    c = compare(x, y, n_comparisons, higher_is_better=True)
    d = bootstrap_median_difference(x, y)
    text = f"{ours} vs {baseline}: {d['difference']:+.2f} dB median PSNR"
    text += ", 95% CI n/a" if math.isnan(d["low"]) else f", 95% CI {d['low']:+.2f} to {d['high']:+.2f}"
    tested = f"p = {p_value(c['p_value'])}"
    if n_comparisons > 1:
        tested = f"p x {n_comparisons} = {p_value(c['p_bonferroni'])}"
    if c["significant"]:
        return f"{text}, {'better' if c['better'] else 'worse'}: supported ({tested})"
    if c["too_small"]:
        return f"{text}, not supported: too few trials to support any difference ({c['n_ours']} vs {c['n_baseline']})"
    if math.isnan(d["low"]):
        return f"{text}, not supported ({tested})"
    # Half the interval's width: the smallest difference this run's spread lets it see.
    seen = (d["high"] - d["low"]) / 2
    beyond = f"differences under about {seen:.2f} dB, half the CI's width, are beyond this run"
    return f"{text}, not supported ({tested}; {beyond})"


def verdict_section(results: Results) -> list[Block]:
    """The report's first line: the engine and what comparing ours with each baseline found on
    each scene (median PSNR), computed from the runs, in plain words."""
    engine = results.config.get("engine", "?")
    ours, parts = results.ours, []
    for scene in results.scenes:
        x = results.values(scene, ours, "psnr") if ours else []
        found = [
            _comparison_words(x, y, ours, baseline, max(1, len(results.baselines)))
            for baseline in results.baselines
            if x and (y := results.values(scene, baseline, "psnr"))
        ]
        if found:
            where = f"on {scene}, " if len(results.scenes) > 1 else ""
            parts.append(where + "; ".join(found))
    if not parts:
        return [Paragraph(f"**Verdict** (engine {engine}): no comparison: no runs of both {ours} and a baseline.")]
    return [Paragraph(f"**Verdict** (engine {engine}): " + "; ".join(parts) + ".")]


def summary_section(results: Results) -> list[Block]:
    """One line per scene: the difference of median PSNR to each baseline in dB, with its CI."""
    ours, items = results.ours, []
    for scene in results.scenes:
        x = results.values(scene, ours, "psnr") if ours else []
        parts = []
        for baseline in results.baselines:
            y = results.values(scene, baseline, "psnr")
            if not x or not y:
                continue
            c = compare(x, y, max(1, len(results.baselines)), higher_is_better=True)
            verdict = "significant" if c["significant"] else "n too small" if c["too_small"] else "not significant"
            parts.append(
                f"{median_difference(x, y, 'psnr')} median PSNR vs {baseline} (p x {c['n_comparisons']} = "
                f"{p_value(c['p_bonferroni'])}, {verdict})"
            )
        if x:
            items.append(
                f"{scene}: {ours} median PSNR {summarise(x)['median']:.2f} dB over {len(x)} trials; "
                + ("; ".join(parts) if parts else "no baseline results")
            )
    return [Heading("Summary"), Bullets(items)] if items else []


def _ablation_table(
    results: Results,
    scene: str,
    labels: list[tuple[list[str], str]],
    label_headers: list[str],
    highlight_groups: list[list[int]],
) -> Table:
    """Median and IQR of PSNR, LPIPS, SSIM (the paper's column order) per (labels, method) row,
    the best of each highlight group in bold."""
    methods = [m for _, m in labels]
    body = [list(label) + [m, str(len(results.values(scene, m, "psnr")))] for label, m in labels]
    headers = label_headers + ["method", "n"]
    for metric in ("psnr", "lpips", "ssim"):
        for statistic in ("median", "iqr"):
            values = [summarise(v)[statistic] if (v := results.values(scene, m, metric)) else None for m in methods]
            cells = [number(v, METRIC_DECIMALS[metric]) for v in values]
            lower = statistic == "iqr" or not HIGHER_IS_BETTER[metric]
            for group in highlight_groups:
                for i, cell in zip(group, bold_best([cells[i] for i in group], [values[i] for i in group], lower)):
                    cells[i] = cell
            for row, cell in zip(body, cells):
                row.append(cell)
            headers.append(f"{METRIC_LABELS[metric]} {'median' if statistic == 'median' else 'IQR'}")
    lacking = any(r.metric("lpips") is None for m in methods for r in results.runs_of(scene, m))
    notes = [f"LPIPS n/a: not computed in some runs; why is noted under the {scene} table."] if lacking else []
    return Table(headers, body, notes)


def _present(results: Results, scene: str, methods) -> list[str]:
    return [m for m in methods if results.values(scene, m, "psnr")]


def table_i_section(results: Results, paper: PaperTables) -> list[Block]:
    row_labels = {method: label for label, method in paper.table_i}
    blocks: list[Block] = []
    for scene in results.scenes:
        present = _present(results, scene, row_labels)
        if "ours" not in present or len(present) < 2:
            continue
        labels = [([row_labels[m]], m) for m in present]
        table = _ablation_table(results, scene, labels, ["terms"], [list(range(len(present)))])
        missing = [m for m in row_labels if m not in present]
        if missing:
            table.notes.append(f"Not run: {', '.join(missing)}.")
        blocks += [Heading(f"{scene}", 3), table]
    if not blocks:
        return []
    intro = Paragraph(
        "Impact of the in-distribution (entropy) and out-of-distribution (distance) terms, as the "
        "paper's Table I; the best per column in bold."
    )
    return [Heading("Ablation: uncertainty terms (Table I)"), intro] + blocks


def _pair_comparisons(results: Results, scene: str, table_ii: tuple[tuple[str, str, str], ...]) -> Table | None:
    """Sampling against NBV for each family present in both variants (Bonferroni over the pairs)."""
    pairs = []
    for family in dict.fromkeys(f for f, _, _ in table_ii):
        nbv, sampling = [m for f, _, m in table_ii if f == family]
        x, y = results.values(scene, sampling, "psnr"), results.values(scene, nbv, "psnr")
        if x and y:
            pairs.append((family, sampling, nbv, x, y))
    rows, notes = [], []
    for family, sampling, nbv, x, y in pairs:
        c = compare(x, y, len(pairs), higher_is_better=True)
        rows.append(
            [
                family,
                f"{sampling} vs {nbv}",
                f"{median_difference(x, y, 'psnr')} median PSNR",
                p_value(c["p_value"]),
                p_value(c["p_bonferroni"]),
                _significance(c),
            ]
        )
        if c["too_small"] and c["note"] not in notes:
            notes.append(c["note"])
    if not rows:
        return None
    k = len(pairs)
    return Table(
        ["family", "sampling vs NBV", "change of the median", "p", f"p x {k} (Bonferroni)", "significant"],
        rows,
        [f"Two-sided Mann-Whitney U on PSNR, Bonferroni x{k} (the pairs compared)."]
        + [f"n too small: {n}." for n in notes],
    )


def table_ii_section(results: Results, paper: PaperTables) -> list[Block]:
    blocks: list[Block] = []
    for scene in results.scenes:
        present = set(_present(results, scene, [m for _, _, m in paper.table_ii]))
        rows = [row for row in paper.table_ii if row[2] in present]
        families = {f for f, _, _ in rows}
        if not any(sum(f == g for g, _, _ in rows) == 2 for f in families):
            continue  # the table is about NBV vs sampling: it needs at least one complete pair
        groups = [[i for i, row in enumerate(rows) if row[0] == f] for f in dict.fromkeys(f for f, _, _ in rows)]
        table = _ablation_table(results, scene, [([f, v], m) for f, v, m in rows], ["family", "variant"], groups)
        table.notes.insert(0, "Best of each family's two variants in bold, as in the paper.")
        missing = [m for _, _, m in paper.table_ii if m not in present]
        if missing:
            table.notes.append(f"Not run: {', '.join(missing)}.")
        blocks += [Heading(f"{scene}", 3), table]
        pairs = _pair_comparisons(results, scene, paper.table_ii)
        if pairs is not None:
            blocks.append(pairs)
    if not blocks:
        return []
    intro = Paragraph(
        "Sampling from each method's uncertainty against taking its top views (NBV), as the paper's Table II."
    )
    return [Heading("Ablation: NBV vs sampling (Table II)"), intro] + blocks


def timing_section(results: Results, paper: PaperTables) -> list[Block]:
    # "curve" (the test views scored between rounds) only where some run was played in rounds.
    phases = [p for p in TIMING_FIELDS if p != "curve" or any(r.seconds(p) is not None for r in results.runs)]
    rows = []
    for method in results.methods:
        runs = results.runs_of(method=method)
        cells = [method, str(len(runs))]
        for phase in phases:
            values = [v for r in runs if (v := r.seconds(phase)) is not None]
            cells.append(seconds(float(np.median(values))) if values else "n/a")
        rows.append(cells)
    if not rows:
        return []
    total = sum(r.seconds("total") or 0.0 for r in results.runs)
    return [
        Heading("Run times"),
        Table(
            ["method", "runs"] + phases,
            rows,
            [
                "Median over all aggregated runs of the method (all scenes), per phase: wall-clock times measured "
                "under the machine's load while the sweep ran (runs side by side share its cores), so methods doing "
                "the same work can differ by the load alone; compare phases that differ in work, not these "
                "seconds, across methods."
            ],
        ),
        Paragraph(
            f"Sweep total: {seconds(total)} of run time summed over {len(results.runs)} aggregated runs "
            f"(wall-clock time is shorter when runs ran in parallel). {paper_run_times(paper.resolution)}"
        ),
    ]


def paper_run_times(side: int) -> str:
    """The sentence citing the paper's run times (PAPER_MINUTES_PER_RUN, at `side` x `side` pixels)."""
    return (
        f"The paper reports about {PAPER_MINUTES_PER_RUN['ours']} min per run for ours and "
        f"{PAPER_MINUTES_PER_RUN['others']} min for the others at {side}x{side} on {PAPER_GPU}."
    )


def problems_section(results: Results) -> list[Block]:
    blocks: list[Block] = [Heading("Runs not aggregated")]
    if not results.not_aggregated and not results.missing:
        return blocks + [Paragraph("None: every run folder holds a valid result for this configuration.")]
    if results.not_aggregated:
        rows = [[f.folder.relative_to(results.root).as_posix(), f.reason] for f in results.not_aggregated]
        blocks += [
            Paragraph("These run folders are left out of every table and figure:"),
            Table(["run folder", "reason"], rows),
        ]
    if results.missing:
        blocks += [Paragraph("Planned by the configuration but never run (no folder):"), Bullets(results.missing)]
    blocks.append(Paragraph("Re-running the same `nerfaug run` command redoes those of them its configuration plans."))
    return blocks


def figure_sections(results: Results, figures: Figures) -> list[Block]:
    blocks: list[Block] = []
    if figures.maps:
        blocks.append(Heading("Uncertainty over the hemisphere (Fig. 1)"))
        blocks.append(
            Paragraph(
                "Each method's scores over the candidate views (its first trial), seen from above: "
                "the centre is straight above the object, the rim the horizon; bright = uncertain "
                "(min-max normalised per panel). Triangles: the initial views; stars: the views "
                "the method chose. Grey: no candidate lies there, so nothing was scored (a pool of "
                "captured views seldom holds one from straight above), or, over a whole panel, a "
                "method such as uniform that gives every candidate the same score."
            )
        )
    for scene, paths in figures.maps.items():
        blocks += [Figure(p, f"Fig. 1 ({scene}): uncertainty maps per method") for p in paths]
        blocks += [Paragraph(note) for note in figures.map_notes.get(scene, [])]
    if figures.renders:
        blocks.append(Heading("Test renders (Fig. 3)"))
        blocks += [
            Figure(
                p,
                f"Fig. 3 ({scene}): test renders after training, ground truth on top, one row per "
                "method (its first trial)",
            )
            for scene, p in figures.renders.items()
        ]
    if figures.curves is not None:
        blocks += [
            Heading("Training curves"),
            Figure(
                figures.curves,
                "Training curves: median over trials per "
                "method, IQR shaded; the dashed line marks the step where the "
                "chosen views were added.",
            ),
        ]
    return blocks


__all__ = [
    "PaperTables",
    "figure_sections",
    "header_section",
    "problems_section",
    "scene_section",
    "summary_section",
    "table_i_section",
    "table_ii_section",
    "timing_section",
]
