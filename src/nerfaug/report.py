"""The report of a results folder: median/IQR tables with Mann-Whitney U tests, the paper's
ablation tables and figures, run times and the runs left out, as `report.md` and a self-contained
`report.html` (figures embedded as data URIs), with the figures as PNGs under `figures/`.

Only runs whose result.json is valid for the sweep's fingerprint (`store.read_result`) are
aggregated; every other run folder is listed with the reason, never silently counted.
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
import platform
import re
import tempfile
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from nerfaug.data.frames import atomic_write_bytes
from nerfaug.experiment.config import TABLE_I, TABLE_II
from nerfaug.experiment.store import RESULT_FILE, RESULT_KEYS, read_result
from nerfaug.statistics import compare, markdown_table, summarise, summary_table

METRICS = ("psnr", "ssim", "lpips")
METRIC_LABELS = {"psnr": "PSNR", "ssim": "SSIM", "lpips": "LPIPS"}
HIGHER_IS_BETTER = {"psnr": True, "ssim": True, "lpips": False}
# Decimals per metric: dB to 0.01 is below any trial-to-trial spread; SSIM/LPIPS IQRs are ~1e-3.
METRIC_DECIMALS = {"psnr": 2, "ssim": 4, "lpips": 4}
TIMING_FIELDS = ("setup", "train_before", "selection", "oracle", "train_after", "evaluation", "total")
TABLE_I_LABELS = {"ours": "Combined (ours)", "entropy-sampling": "Entropy only", "distance": "Distance only"}
# Table II rows: (family, variant, method name), in the paper's order.
TABLE_II_ROWS = (
    ("Ours", "NBV", "ours-nbv"), ("Ours", "Sampling", "ours"),
    ("FisherRF", "NBV", "fisherrf"), ("FisherRF", "Sampling", "fisherrf-sampling"),
    ("Entropy", "NBV", "entropy"), ("Entropy", "Sampling", "entropy-sampling"),
)
FIGURE_DPI = 110


class ReportError(RuntimeError):
    """The folder is not a results folder the report can read."""


# ----------------------------------------------------------------------------- collecting runs


@dataclass(frozen=True)
class Run:
    """One aggregated run: its valid result.json and its folder (for selection, renders, history)."""

    scene: str
    method: str
    trial: int
    folder: Path
    result: dict

    def metric(self, name: str) -> float | None:
        value = self.result["metrics"].get(name)
        return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else None

    def seconds(self, phase: str) -> float | None:
        timing = self.result["timing"]
        value = timing.get(phase) if isinstance(timing, dict) else None
        return float(value) if isinstance(value, (int, float)) else None


@dataclass(frozen=True)
class NotAggregated:
    folder: Path
    reason: str


@dataclass
class Results:
    """What a results folder holds, split into aggregated runs and the rest."""

    root: Path
    sweep: dict
    runs: list[Run]
    not_aggregated: list[NotAggregated]
    missing: list[str]
    scenes: list[str] = field(default_factory=list)
    methods: list[str] = field(default_factory=list)

    @property
    def config(self) -> dict:
        return self.sweep.get("config", {})

    @property
    def ours(self) -> str | None:
        """The method compared with the others: the first of the config's methods."""
        configured = self.config.get("methods") or self.methods
        return configured[0] if configured else None

    @property
    def baselines(self) -> list[str]:
        present = {run.method for run in self.runs}
        return [m for m in self.methods if m != self.ours and m in present]

    def runs_of(self, scene: str | None = None, method: str | None = None) -> list[Run]:
        chosen = [r for r in self.runs
                  if (scene is None or r.scene == scene) and (method is None or r.method == method)]
        return sorted(chosen, key=lambda r: (r.scene, r.method, r.trial))

    def values(self, scene: str, method: str, metric: str) -> list[float]:
        return [v for r in self.runs_of(scene, method) if (v := r.metric(metric)) is not None]


def read_sweep(root: Path) -> dict:
    path = root / "sweep.json"
    if not path.is_file():
        raise ReportError(f"{path} not found: {root} is not a results folder written by `nerfaug run`")
    try:
        sweep = json.loads(path.read_text())
    except json.JSONDecodeError as error:
        raise ReportError(f"{path}: invalid JSON ({error.msg} at line {error.lineno})") from None
    if not isinstance(sweep, dict) or "fingerprint" not in sweep:
        raise ReportError(f"{path}: no fingerprint; not a sweep record")
    return sweep


def why_not_valid(folder: Path, fingerprint: str) -> str:
    """A human reason why `read_result(folder, fingerprint)` refused the run (for the report only;
    the decision itself is `read_result`'s)."""
    path = folder / RESULT_FILE
    if not path.exists() and (folder / "error.json").exists():
        try:
            return f"failed: {json.loads((folder / 'error.json').read_text())['error']}"
        except (OSError, ValueError, KeyError, TypeError):
            pass
    if not path.exists():
        progress = folder / "progress.json"
        step = ""
        if progress.exists():
            try:
                step = f", last progress at step {json.loads(progress.read_text())['step']}"
            except (OSError, ValueError, KeyError, TypeError):
                pass
        return f"no result.json (interrupted, failed or still running{step})"
    try:
        result = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as error:
        return f"result.json unreadable or truncated ({getattr(error, 'msg', error)})"
    if not isinstance(result, dict):
        return "result.json is not a JSON object"
    missing = [key for key in RESULT_KEYS if key not in result]
    if missing:
        return f"result.json lacks {', '.join(missing)}"
    if result["fingerprint"] != fingerprint:
        return f"made with another configuration (fingerprint {result['fingerprint']}, sweep {fingerprint})"
    return "result.json has no numeric PSNR"


def _run_folders(root: Path) -> list[Path]:
    return sorted(p for p in (root / "runs").glob("*/*/*") if p.is_dir())


def _read_run(folder: Path, fingerprint: str) -> Run | NotAggregated:
    scene, method, name = folder.parts[-3:]
    match = re.fullmatch(r"trial_(\d+)", name)
    if match is None:
        return NotAggregated(folder, "folder name is not trial_<k>")
    result = read_result(folder, fingerprint)
    if result is None:
        return NotAggregated(folder, why_not_valid(folder, fingerprint))
    trial = int(match.group(1))
    claimed = (str(result["scene"]), str(result["method"]), result["trial"])
    if claimed != (scene, method, trial):
        where = f"{claimed[0]}/{claimed[1]}/trial {claimed[2]}"
        return NotAggregated(folder, f"result.json is for {where}, not this folder")
    return Run(scene, method, trial, folder, result)


def _ordered(configured: list[str], found: set[str]) -> list[str]:
    """The config's order first (the first method is ours), then anything else found, sorted."""
    return [x for x in configured if x in found] + sorted(found - set(configured))


def collect_results(results_dir: Path) -> Results:
    """Read a results folder: the sweep record, every run folder (valid or not) and the planned
    runs that have no folder at all."""
    root = Path(results_dir)
    sweep = read_sweep(root)
    runs, skipped = [], []
    for folder in _run_folders(root):
        item = _read_run(folder, sweep["fingerprint"])
        (runs if isinstance(item, Run) else skipped).append(item)
    config = sweep.get("config", {})
    # Results name a user dataset by its folder's name (sweep.scene_name).
    planned_scenes = [Path(s).name for s in config.get("scenes", [])]
    planned_methods = list(config.get("methods", []))
    existing = {tuple(folder.parts[-3:]) for folder in _run_folders(root)}
    missing = [
        f"{scene}/{method}/trial {trial}"
        for scene in planned_scenes for method in planned_methods for trial in range(int(config.get("trials", 0)))
        if (scene, method, f"trial_{trial:03d}") not in existing
    ]
    scenes = _ordered(planned_scenes, {r.scene for r in runs} | {f.folder.parts[-3] for f in skipped})
    methods = _ordered(planned_methods, {r.method for r in runs})
    return Results(root, sweep, runs, skipped, missing, scenes, methods)


# ----------------------------------------------------------------------------- document blocks


@dataclass
class Heading:
    text: str
    level: int = 2


@dataclass
class Paragraph:
    text: str


@dataclass
class Bullets:
    items: list[str]


@dataclass
class Code:
    text: str
    summary: str | None = None
    """If given, the block is collapsed behind this summary."""


@dataclass
class Table:
    headers: list[str]
    rows: list[list[str]]
    notes: list[str] = field(default_factory=list)


@dataclass
class Figure:
    path: Path
    caption: str


Block = Heading | Paragraph | Bullets | Code | Table | Figure


def to_markdown(blocks: list[Block], root: Path) -> str:
    parts = []
    for block in blocks:
        if isinstance(block, Heading):
            parts.append("#" * block.level + " " + block.text)
        elif isinstance(block, Paragraph):
            parts.append(block.text)
        elif isinstance(block, Bullets):
            parts.append("\n".join(f"- {item}" for item in block.items))
        elif isinstance(block, Code):
            code = f"```\n{block.text}\n```"
            if block.summary is not None:
                code = f"<details><summary>{block.summary}</summary>\n\n{code}\n\n</details>"
            parts.append(code)
        elif isinstance(block, Table):
            rows = [dict(enumerate(row)) for row in block.rows]
            table = markdown_table(rows, [(i, h) for i, h in enumerate(block.headers)]).rstrip()
            parts.append("\n\n".join([table, *block.notes]))
        elif isinstance(block, Figure):
            parts.append(f"![{block.caption}]({block.path.relative_to(root).as_posix()})\n\n*{block.caption}*")
    return "\n\n".join(parts) + "\n"


def _inline_html(text: str) -> str:
    """Escape, then the two Markdown inline marks this report uses: **bold** and `code`."""
    text = html.escape(text, quote=False)
    text = re.sub(r"\*\*(.+?)\*\*", r"<strong>\1</strong>", text)
    return re.sub(r"`([^`]+)`", r"<code>\1</code>", text)


def _data_uri(path: Path) -> str:
    return "data:image/png;base64," + base64.b64encode(path.read_bytes()).decode("ascii")


_NUMBER = re.compile(r"^[-+*]*[0-9.]")


def _html_table(table: Table) -> str:
    head = "".join(f"<th>{_inline_html(h)}</th>" for h in table.headers)
    body = []
    for row in table.rows:
        cells = "".join(
            f'<td class="num">{_inline_html(c)}</td>' if _NUMBER.match(c) else f"<td>{_inline_html(c)}</td>"
            for c in row
        )
        body.append(f"<tr>{cells}</tr>")
    notes = "".join(f'<p class="note">{_inline_html(n)}</p>' for n in table.notes)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>{notes}"


def _html_block(block: Block) -> str:
    if isinstance(block, Heading):
        return f"<h{block.level}>{_inline_html(block.text)}</h{block.level}>"
    if isinstance(block, Paragraph):
        return f"<p>{_inline_html(block.text)}</p>"
    if isinstance(block, Bullets):
        return "<ul>" + "".join(f"<li>{_inline_html(i)}</li>" for i in block.items) + "</ul>"
    if isinstance(block, Code):
        code = f"<pre>{html.escape(block.text)}</pre>"
        if block.summary is None:
            return code
        return f"<details><summary>{html.escape(block.summary)}</summary>{code}</details>"
    if isinstance(block, Table):
        return _html_table(block)
    alt = html.escape(block.caption)
    return f'<figure><img src="{_data_uri(block.path)}" alt="{alt}"><figcaption>{alt}</figcaption></figure>'


# Inline so the file is self-contained: it must open from an e-mail or an offline machine.
_CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",sans-serif;max-width:1200px;margin:2em auto;
padding:0 1em;color:#222;line-height:1.45}
h1{border-bottom:2px solid #444}h2{border-bottom:1px solid #bbb;margin-top:2em}
table{border-collapse:collapse;margin:0.8em 0;font-size:0.9em}
th,td{border:1px solid #ccc;padding:3px 8px}th{background:#eee}td.num{text-align:right;
font-variant-numeric:tabular-nums}tr:nth-child(even) td{background:#fafafa}
pre{background:#f4f4f4;padding:0.6em;overflow-x:auto;font-size:0.85em}
code{background:#f4f4f4;padding:0 3px}p.note{font-size:0.85em;color:#555;margin:0.2em 0}
figure{margin:1em 0}figure img{max-width:100%;height:auto;border:1px solid #ddd}
figcaption{font-size:0.9em;color:#444}details{margin:0.5em 0}summary{cursor:pointer}
"""


def to_html(blocks: list[Block], title: str) -> str:
    body = "\n".join(_html_block(b) for b in blocks)
    return (
        f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        f"<title>{html.escape(title)}</title><style>{_CSS}</style></head>\n<body>\n{body}\n</body></html>\n"
    )


# ----------------------------------------------------------------------------- formatting


def _number(value: float | None, decimals: int) -> str:
    if value is None:
        return "n/a"
    if math.isnan(value):
        return "nan"
    if math.isinf(value):
        return "inf" if value > 0 else "-inf"
    return f"{value:.{decimals}f}"


def _percent(fraction: float | None) -> str:
    if fraction is None or math.isnan(fraction):
        return "n/a"
    return f"{fraction * 100:+.1f}%"


def _p(value: float | None) -> str:
    if value is None:
        return "n/a"
    return f"{value:.1e}" if value < 1e-3 else f"{value:.3f}"


def _seconds(value: float | None) -> str:
    if value is None or math.isnan(value):
        return "n/a"
    if value < 60:
        return f"{value:.1f} s"
    minutes, seconds = divmod(round(value), 60)
    if minutes < 60:
        return f"{minutes}m {seconds:02d}s"
    hours, minutes = divmod(minutes, 60)
    return f"{hours}h {minutes:02d}m"


def _slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name)


def _bold_best(cells: list[str], values: list[float | None], lower_is_better: bool) -> list[str]:
    """Bold the best value (the paper highlights the best method per column). Ties are judged on
    the cells as shown, so values equal to the shown precision are all bold; if all are, none is."""
    finite = [(v, c) for v, c in zip(values, cells) if v is not None and math.isfinite(v)]
    if len({c for _, c in finite}) < 2:
        return cells
    best = (min if lower_is_better else max)(finite)[1]
    return [f"**{c}**" if c == best else c for c in cells]


def _lpips_notes(runs: list[Run]) -> list[str]:
    statuses = sorted({str(r.result.get("lpips_status", "unknown reason")) for r in runs if r.metric("lpips") is None})
    return [f"LPIPS n/a: {status}" for status in statuses]


# ----------------------------------------------------------------------------- sections


def header_section(results: Results) -> list[Block]:
    config, sweep = results.config, results.sweep
    methods = ", ".join(_label(results, m) for m in config.get("methods", results.methods))
    planned = len(config.get("scenes", [])) * len(config.get("methods", [])) * int(config.get("trials", 0))
    hosts = sorted({str(r.result.get("host")) for r in results.runs if r.result.get("host")})
    versions = sweep.get("versions", {})
    command = sweep.get("command") or []
    blocks: list[Block] = [
        Heading(f"nerfaug report: {results.root.name}", 1),
        Bullets([
            f"scenes: {', '.join(config.get('scenes', results.scenes))}",
            f"methods: {methods}",
            f"trials per scene and method: {config.get('trials', '?')} (trial k uses seed {config.get('seed', 0)} + k)",
            f"steps: {config.get('steps', '?')}; {config.get('n_new', '?')} views added at step "
            f"{config.get('add_at_step', '?')} to {config.get('n_initial', '?')} initial views",
            f"engine preset: {config.get('engine', '?')}; resolution: {config.get('resolution', '?')} px; "
            f"test views: {config.get('n_test', '?')}; candidate pool: {config.get('pool', '?')}",
            f"runs aggregated: {len(results.runs)} of {planned} planned; not aggregated: "
            f"{len(results.not_aggregated)}; never run: {len(results.missing)}",
            f"fingerprint: `{sweep.get('fingerprint')}`",
            f"report written {datetime.now(timezone.utc):%Y-%m-%d %H:%M UTC} on {platform.node()}; "
            f"runs made on: {', '.join(hosts) or 'n/a'}",
            "versions: " + ", ".join(f"{k} {v}" for k, v in versions.items()),
        ]),
        Paragraph("Command:"),
        Code(" ".join(str(part) for part in command) if isinstance(command, list) else str(command)),
        Code(json.dumps(config, indent=2, default=str), summary="configuration (JSON)"),
    ]
    if results.not_aggregated or results.missing:
        blocks.append(Paragraph(
            f"**Warning:** {len(results.not_aggregated)} run folder(s) were not aggregated and "
            f"{len(results.missing)} planned run(s) never ran; see \"Runs not aggregated\" at the end."
        ))
    return blocks


def _summary_rows(results: Results, scene: str) -> dict[str, dict[str, dict]]:
    """method -> metric -> summary_table row, for one scene."""
    records = [{"scene": r.scene, "method": r.method, "trial": r.trial, **{m: r.metric(m) for m in METRICS}}
               for r in results.runs_of(scene)]
    rows: dict[str, dict[str, dict]] = {}
    for metric in METRICS:
        table = summary_table(records, metric, results.ours or "", results.baselines,
                              n_comparisons=max(1, len(results.baselines)), higher_is_better=HIGHER_IS_BETTER[metric])
        for row in table:
            rows.setdefault(row["method"], {})[metric] = row
    return rows


def _median_table(results: Results, scene: str, rows: dict[str, dict[str, dict]]) -> Table:
    methods = [m for m in results.methods if m in rows]
    headers = ["method", "n"]
    columns: list[list[str]] = [[_label(results, m) for m in methods],
                                [str(rows[m]["psnr"]["n"]) for m in methods]]
    for metric in METRICS:
        arrow = "↑" if HIGHER_IS_BETTER[metric] else "↓"
        headers += [f"{METRIC_LABELS[metric]} {arrow} median", f"{METRIC_LABELS[metric]} IQR"]
        decimals = METRIC_DECIMALS[metric]
        medians = [rows[m][metric]["median"] for m in methods]
        iqrs = [rows[m][metric]["iqr"] for m in methods]
        columns.append(_bold_best([_number(v, decimals) for v in medians], medians, not HIGHER_IS_BETTER[metric]))
        columns.append(_bold_best([_number(v, decimals) for v in iqrs], iqrs, True))
    notes = ["Median and interquartile range (IQR) of each trial's mean over the test views; best per column in bold."]
    notes += _lpips_notes(results.runs_of(scene))
    return Table(headers, [list(row) for row in zip(*columns)], notes)


def _iqr_change(reduction: float | None) -> str:
    """`compare`'s iqr_reduction (positive: ours is tighter) in words."""
    if reduction is None or math.isnan(reduction):
        return "n/a (baseline IQR 0)"
    if abs(reduction) < 5e-4:
        return "equal"
    return f"{abs(reduction) * 100:.1f}% {'smaller' if reduction > 0 else 'larger'}"


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


def _comparison_table(results: Results, rows: dict[str, dict[str, dict]]) -> Table | None:
    k = max(1, len(results.baselines))
    body, notes = [], []
    for baseline in results.baselines:
        for metric in METRICS:
            row = rows.get(baseline, {}).get(metric)
            ours_row = rows.get(results.ours, {}).get(metric)
            if row is None or row["p_value"] is None:
                continue
            label, decimals = METRIC_LABELS[metric], METRIC_DECIMALS[metric]
            body.append([
                baseline, label,
                f"{_number(ours_row['median'], decimals)} vs {_number(row['median'], decimals)}",
                f"{_percent(row['median_change'])} median {label} ({_direction(row, ours_row)})",
                _iqr_change(row["iqr_reduction"]),
                _p(row["p_value"]), _p(row["p_bonferroni"]), _significance(row),
            ])
            if row["too_small"] and row["note"] not in notes:
                notes.append(row["note"])
    if not body:
        return None
    notes = [f"Two-sided Mann-Whitney U test of ours against each baseline, Bonferroni correction x{k} "
             f"(the number of baselines); significant means p x {k} < 0.05."] + [f"n too small: {n}." for n in notes]
    headers = ["baseline", "metric", "median (ours vs baseline)", "change of the median", "IQR of ours vs baseline's",
               "p", f"p x {k} (Bonferroni)", "significant"]
    return Table(headers, body, notes)


def scene_section(results: Results, scene: str, boxplots: Path | None) -> list[Block]:
    blocks: list[Block] = [Heading(f"Scene: {scene}")]
    rows = _summary_rows(results, scene)
    if not rows:
        return blocks + [Paragraph("No aggregated runs for this scene.")]
    blocks.append(_median_table(results, scene, rows))
    comparison = _comparison_table(results, rows) if results.ours in rows else None
    if comparison is not None:
        blocks += [Paragraph(f"**{_label(results, results.ours)}** against each baseline on {scene}:"), comparison]
    elif results.ours not in rows:
        blocks.append(Paragraph(f"No aggregated runs of {_label(results, results.ours)} on {scene}: no comparison."))
    if boxplots is not None:
        caption = f"Fig. 4 ({scene}): PSNR, SSIM and LPIPS per method over trials; each dot is one trial."
        blocks.append(Figure(boxplots, caption))
    return blocks


def summary_section(results: Results) -> list[Block]:
    """One line per scene with the paper's headline phrasing ("+66.7% median PSNR")."""
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
            parts.append(f"{_percent(c['median_change'])} median PSNR vs {baseline} (p x {c['n_comparisons']} = "
                         f"{_p(c['p_bonferroni'])}, {verdict})")
        if x:
            items.append(f"{scene}: {ours} median PSNR {summarise(x)['median']:.2f} dB over {len(x)} trials; "
                         + ("; ".join(parts) if parts else "no baseline results"))
    return [Heading("Summary"), Bullets(items)] if items else []


def _ablation_table(results: Results, scene: str, labels: list[tuple[list[str], str]], label_headers: list[str],
                    highlight_groups: list[list[int]]) -> Table:
    """Median and IQR of PSNR, LPIPS, SSIM (the paper's column order) per (labels, method) row,
    the best of each highlight group in bold."""
    methods = [m for _, m in labels]
    body = [list(label) + [m, str(len(results.values(scene, m, "psnr")))] for label, m in labels]
    headers = label_headers + ["method", "n"]
    for metric in ("psnr", "lpips", "ssim"):
        for statistic in ("median", "iqr"):
            values = [summarise(v)[statistic] if (v := results.values(scene, m, metric)) else None for m in methods]
            cells = [_number(v, METRIC_DECIMALS[metric]) for v in values]
            lower = statistic == "iqr" or not HIGHER_IS_BETTER[metric]
            for group in highlight_groups:
                for i, cell in zip(group, _bold_best([cells[i] for i in group], [values[i] for i in group], lower)):
                    cells[i] = cell
            for row, cell in zip(body, cells):
                row.append(cell)
            headers.append(f"{METRIC_LABELS[metric]} {'median' if statistic == 'median' else 'IQR'}")
    lacking = any(r.metric("lpips") is None for m in methods for r in results.runs_of(scene, m))
    notes = [f"LPIPS n/a: not computed in some runs; why is noted under the {scene} table."] if lacking else []
    return Table(headers, body, notes)


def _present(results: Results, scene: str, methods) -> list[str]:
    return [m for m in methods if results.values(scene, m, "psnr")]


def table_i_section(results: Results) -> list[Block]:
    blocks: list[Block] = []
    for scene in results.scenes:
        present = _present(results, scene, TABLE_I)
        if "ours" not in present or len(present) < 2:
            continue
        labels = [([TABLE_I_LABELS[m]], m) for m in present]
        table = _ablation_table(results, scene, labels, ["terms"], [list(range(len(present)))])
        missing = [m for m in TABLE_I if m not in present]
        if missing:
            table.notes.append(f"Not run: {', '.join(missing)}.")
        blocks += [Heading(f"{scene}", 3), table]
    if not blocks:
        return []
    intro = Paragraph("Impact of the in-distribution (entropy) and out-of-distribution (distance) terms, as the "
                      "paper's Table I; the best per column in bold.")
    return [Heading("Ablation: uncertainty terms (Table I)"), intro] + blocks


def _pair_comparisons(results: Results, scene: str) -> Table | None:
    """Sampling against NBV for each family present in both variants (Bonferroni over the pairs)."""
    pairs = []
    for family in dict.fromkeys(f for f, _, _ in TABLE_II_ROWS):
        nbv, sampling = [m for f, _, m in TABLE_II_ROWS if f == family]
        x, y = results.values(scene, sampling, "psnr"), results.values(scene, nbv, "psnr")
        if x and y:
            pairs.append((family, sampling, nbv, x, y))
    rows, notes = [], []
    for family, sampling, nbv, x, y in pairs:
        c = compare(x, y, len(pairs), higher_is_better=True)
        rows.append([family, f"{sampling} vs {nbv}", f"{_percent(c['median_change'])} median PSNR",
                     _p(c["p_value"]), _p(c["p_bonferroni"]), _significance(c)])
        if c["too_small"] and c["note"] not in notes:
            notes.append(c["note"])
    if not rows:
        return None
    k = len(pairs)
    return Table(["family", "sampling vs NBV", "change of the median", "p", f"p x {k} (Bonferroni)", "significant"],
                 rows, [f"Two-sided Mann-Whitney U on PSNR, Bonferroni x{k} (the pairs compared)."]
                 + [f"n too small: {n}." for n in notes])


def table_ii_section(results: Results) -> list[Block]:
    blocks: list[Block] = []
    for scene in results.scenes:
        present = set(_present(results, scene, TABLE_II))
        rows = [row for row in TABLE_II_ROWS if row[2] in present]
        families = {f for f, _, _ in rows}
        if not any(sum(f == g for g, _, _ in rows) == 2 for f in families):
            continue  # the table is about NBV vs sampling: it needs at least one complete pair
        groups = [[i for i, row in enumerate(rows) if row[0] == f] for f in dict.fromkeys(f for f, _, _ in rows)]
        table = _ablation_table(results, scene, [([f, v], m) for f, v, m in rows], ["family", "variant"], groups)
        table.notes.insert(0, "Best of each family's two variants in bold, as in the paper.")
        missing = [m for _, _, m in TABLE_II_ROWS if m not in present]
        if missing:
            table.notes.append(f"Not run: {', '.join(missing)}.")
        blocks += [Heading(f"{scene}", 3), table]
        pairs = _pair_comparisons(results, scene)
        if pairs is not None:
            blocks.append(pairs)
    if not blocks:
        return []
    intro = Paragraph("Sampling from each method's uncertainty against taking its top views (NBV), as the "
                      "paper's Table II.")
    return [Heading("Ablation: NBV vs sampling (Table II)"), intro] + blocks


def timing_section(results: Results) -> list[Block]:
    rows = []
    for method in results.methods:
        runs = results.runs_of(method=method)
        cells = [method, str(len(runs))]
        for phase in TIMING_FIELDS:
            values = [v for r in runs if (v := r.seconds(phase)) is not None]
            cells.append(_seconds(float(np.median(values))) if values else "n/a")
        rows.append(cells)
    if not rows:
        return []
    total = sum(r.seconds("total") or 0.0 for r in results.runs)
    return [
        Heading("Run times"),
        Table(["method", "runs"] + list(TIMING_FIELDS), rows,
              ["Median over all aggregated runs of the method (all scenes), per phase."]),
        Paragraph(f"Sweep total: {_seconds(total)} of run time summed over {len(results.runs)} aggregated runs "
                  "(wall-clock time is shorter when runs ran in parallel). The paper reports about 11 min per "
                  "run for ours and 8 min for the others at 800x800 on one RTX 6000 Ada."),
    ]


def problems_section(results: Results) -> list[Block]:
    blocks: list[Block] = [Heading("Runs not aggregated")]
    if not results.not_aggregated and not results.missing:
        return blocks + [Paragraph("None: every run folder holds a valid result for this configuration.")]
    if results.not_aggregated:
        rows = [[f.folder.relative_to(results.root).as_posix(), f.reason] for f in results.not_aggregated]
        blocks += [Paragraph("These run folders are left out of every table and figure:"),
                   Table(["run folder", "reason"], rows)]
    if results.missing:
        blocks += [Paragraph("Planned by the configuration but never run (no folder):"), Bullets(results.missing)]
    blocks.append(Paragraph("Re-running the same `nerfaug run` command redoes those of them its configuration plans."))
    return blocks


# ----------------------------------------------------------------------------- figures


def _method_colours(methods: list[str]) -> dict[str, tuple]:
    from matplotlib import colormaps

    palette = colormaps["tab10"].colors
    return {m: palette[i % len(palette)] for i, m in enumerate(methods)}


def _save(figure, path: Path) -> Path:
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=FIGURE_DPI, bbox_inches="tight")
    atomic_write_bytes(path, buffer.getvalue())
    return path


def _new_figure(width: float, height: float):
    # The object-oriented API (no pyplot): no global state and no GUI backend, safe in any process.
    from matplotlib.figure import Figure as MplFigure

    return MplFigure(figsize=(width, height))


def plot_boxplots(results: Results, scene: str, path: Path) -> Path | None:
    """Fig. 4: one panel per metric, one box per method over trials, each trial as a dot."""
    methods = [m for m in results.methods if results.runs_of(scene, m)]
    if not methods:
        return None
    colours = _method_colours(results.methods)
    data_by_metric = {metric: [results.values(scene, m, metric) for m in methods] for metric in METRICS}
    # A metric with no values keeps a narrow panel that says so, rather than vanishing.
    widths = [1.0 if any(data_by_metric[metric]) else 0.35 for metric in METRICS]
    figure = _new_figure(max(8.0, 0.75 * len(methods) * sum(widths)), 3.8)
    axes = figure.subplots(1, len(METRICS), gridspec_kw={"width_ratios": widths})
    jitter = np.random.default_rng(0)
    for ax, metric in zip(axes, METRICS):
        data = data_by_metric[metric]
        arrow = "higher is better" if HIGHER_IS_BETTER[metric] else "lower is better"
        ax.set_title(f"{METRIC_LABELS[metric]} ({arrow})", fontsize=10)
        if not any(data):
            ax.text(0.5, 0.5, f"{METRIC_LABELS[metric]}\nn/a\n(not computed\nin these runs)", ha="center", va="center",
                    transform=ax.transAxes, color="0.4")
            ax.set_xticks([])
            ax.set_yticks([])
            continue
        positions = [i for i, d in enumerate(data) if d]
        boxes = ax.boxplot([data[i] for i in positions], positions=positions, widths=0.6, patch_artist=True,
                           showfliers=False, medianprops={"color": "black"})
        for patch, i in zip(boxes["boxes"], positions):
            patch.set_facecolor((*colours[methods[i]][:3], 0.35))
        for i in positions:
            x = i + jitter.uniform(-0.12, 0.12, len(data[i]))
            ax.scatter(x, data[i], s=14, color=colours[methods[i]], edgecolor="black", linewidth=0.4, zorder=3)
        ax.set_xticks(range(len(methods)), methods, rotation=30, ha="right", fontsize=9)
        ax.set_xlim(-0.6, len(methods) - 0.4)
        ax.grid(axis="y", alpha=0.3)
    figure.suptitle(f"{scene}: test metrics over trials", fontsize=11)
    return _save(figure, path)


def _read_json(path: Path):
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def _first_run_with(results: Results, scene: str, method: str, filename: str) -> Run | None:
    """The lowest trial that has `filename` (trial 0 unless it is missing)."""
    return next((r for r in results.runs_of(scene, method) if (r.folder / filename).exists()), None)


MAP_PANELS_PER_FIGURE = 4  # wider figures shrink each hemisphere below legibility in the HTML page


def _map_panels(results: Results, scene: str) -> tuple[list, list[str]]:
    """(method, trial, selection) for each method's lowest trial with a selection.json whose
    candidates are the scene's shared pool; and notes on methods left out."""
    panels, notes, pool = [], [], None
    for method in results.methods:
        run = _first_run_with(results, scene, method, "selection.json")
        selection = _read_json(run.folder / "selection.json") if run else None
        if not isinstance(selection, dict) or not {"candidate_poses", "scores", "train_poses"} <= selection.keys():
            continue
        candidates = np.asarray(selection["candidate_poses"], dtype=np.float64)
        if pool is None:
            pool = candidates
        elif candidates.shape != pool.shape or not np.allclose(candidates, pool, atol=1e-5):
            notes.append(f"{method} left out: its candidate poses differ from {panels[0][0]}'s")
            continue
        panels.append((method, run.trial, selection))
    return panels, notes


def plot_uncertainty_maps(results: Results, scene: str, folder: Path) -> tuple[list[Path], list[str]]:
    """Fig. 1: per method, its first trial's scores over the hemisphere with the initial (triangles)
    and chosen (stars) views, drawn by `nerfaug.maps.plot_method_maps`, at most
    MAP_PANELS_PER_FIGURE methods per image. Returns the images and notes."""
    from nerfaug.maps import plot_method_maps

    panels, notes = _map_panels(results, scene)
    paths = []
    for part, first in enumerate(range(0, len(panels), MAP_PANELS_PER_FIGURE)):
        chunk = panels[first: first + MAP_PANELS_PER_FIGURE]
        maps = {f"{m} (trial {t})": (np.asarray(s["scores"], dtype=np.float64),
                                     np.asarray(s["chosen_poses"]) if s.get("chosen_poses") else None)
                for m, t, s in chunk}
        suffix = "" if len(panels) <= MAP_PANELS_PER_FIGURE else f"_{part + 1}"
        path = folder / f"fig1_uncertainty_{_slug(scene)}{suffix}.png"
        _write_atomically(path, lambda tmp: plot_method_maps(
            maps, np.asarray(chunk[0][2]["candidate_poses"]), np.asarray(chunk[0][2]["train_poses"]), tmp,
            title=f"{scene}: uncertainty over the hemisphere, seen from above (bright = uncertain)"))
        paths.append(path)
    return paths, notes


def _write_atomically(path: Path, draw) -> None:
    """Let `draw(png_path)` write a PNG somewhere private, then put its bytes in place atomically."""
    with tempfile.TemporaryDirectory() as folder:
        drawn = Path(folder) / path.name
        draw(drawn)
        atomic_write_bytes(path, drawn.read_bytes())


def _read_png(path: Path) -> np.ndarray | None:
    import imageio.v3 as iio

    try:
        return iio.imread(path)[..., :3]
    except Exception:  # imageio raises many types; an unreadable render is left out of the grid
        return None


def _render_rows(results: Results, scene: str) -> tuple[list[tuple[str, list]], int]:
    """(label, images) per row: the ground truth (from a render_vs_gt image), then each method's
    renders of its lowest trial; and the number of columns."""
    rows, ground_truth = [], None
    for method in results.methods:
        run = next((r for r in results.runs_of(scene, method) if any((r.folder / "renders").glob("*_render.png"))),
                   None)
        if run is None:
            continue
        images = [_read_png(p) for p in sorted((run.folder / "renders").glob("*_render.png"))]
        rows.append((f"{method}\n(trial {run.trial})", images))
        if ground_truth is None:
            pairs = [_read_png(p) for p in sorted((run.folder / "renders").glob("*_render_vs_gt.png"))]
            # Render left, ground truth right: the right half is the ground truth.
            ground_truth = [p[:, p.shape[1] // 2:] if p is not None else None for p in pairs]
    if ground_truth:
        rows.insert(0, ("ground truth", ground_truth))
    return rows, max((len(images) for _, images in rows), default=0)


def plot_render_grid(results: Results, scene: str, path: Path) -> Path | None:
    """Fig. 3: the saved test renders, one row per method (ground truth on top)."""
    rows, columns = _render_rows(results, scene)
    if not rows or columns == 0:
        return None
    figure = _new_figure(2.0 * columns + 1.2, 2.0 * len(rows))
    axes = figure.subplots(len(rows), columns, squeeze=False)
    for r, (label, images) in enumerate(rows):
        for c in range(columns):
            ax = axes[r, c]
            ax.set_xticks([])
            ax.set_yticks([])
            for spine in ax.spines.values():
                spine.set_visible(False)
            if c < len(images) and images[c] is not None:
                ax.imshow(images[c])
            if c == 0:
                ax.set_ylabel(label, fontsize=9, rotation=0, ha="right", va="center")
            if r == 0:
                ax.set_title(f"test view {c}", fontsize=9)
    # No title: the report's caption names the scene, and a suptitle collides with the column titles.
    figure.subplots_adjust(wspace=0.03, hspace=0.05)
    return _save(figure, path)


HISTORY_KEYS = ("psnr", "train_psnr", "loss", "train_loss")
HISTORY_LABELS = {"psnr": "training-batch PSNR (dB)", "train_psnr": "training PSNR (dB)", "loss": "training loss",
                  "train_loss": "training loss"}


def history_series(history) -> tuple[str, np.ndarray, np.ndarray] | None:
    """(quantity, steps, values) from a history.json: a list of per-step records
    ({"step": .., "psnr": ..}) or a dict of equal-length lists ({"step": [..], "psnr": [..]}).
    PSNR is preferred; the loss is used when no PSNR was recorded."""
    if isinstance(history, dict):
        steps = history.get("step", history.get("steps"))
        if not isinstance(steps, list):
            return None
        columns = {k: v for k, v in history.items()
                   if k in HISTORY_KEYS and isinstance(v, list) and len(v) == len(steps)}
        records = [{"step": step, **{k: v[i] for k, v in columns.items()}} for i, step in enumerate(steps)]
    elif isinstance(history, list):
        records = [h for h in history if isinstance(h, dict) and isinstance(h.get("step"), (int, float))]
    else:
        return None
    for key in HISTORY_KEYS:
        pairs = [(float(h["step"]), float(h[key])) for h in records if isinstance(h.get(key), (int, float))]
        pairs = [(s, v) for s, v in pairs if math.isfinite(v)]
        if len(pairs) >= 2:
            steps, values = np.array(pairs).T
            order = np.argsort(steps, kind="stable")
            return key, steps[order], values[order]
    return None


CURVE_POINTS = 200  # per-step batch PSNR is noisy: average it over windows down to about this many points


def _smooth(steps: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Window means of consecutive records, about CURVE_POINTS of them."""
    window = max(1, len(steps) // CURVE_POINTS)
    usable = len(steps) // window * window
    return steps[:usable].reshape(-1, window).mean(1), values[:usable].reshape(-1, window).mean(1)


def _median_curve(series: list[tuple[np.ndarray, np.ndarray]]):
    """Median and quartiles over trials on the union of their steps (each trial interpolated
    only within the steps it recorded)."""
    grid = np.unique(np.concatenate([s for s, _ in series]))
    stacked = np.full((len(series), grid.size), np.nan)
    for row, (steps, values) in zip(stacked, series):
        inside = (grid >= steps[0]) & (grid <= steps[-1])
        row[inside] = np.interp(grid[inside], steps, values)
    q1, median, q3 = np.nanpercentile(stacked, [25, 50, 75], axis=0)
    return grid, median, q1, q3


def plot_training_curves(results: Results, path: Path) -> Path | None:
    """Training PSNR (or loss) against step: median over trials per method, IQR shaded, one panel per scene."""
    panels = []
    for scene in results.scenes:
        curves = {}
        for method in results.methods:
            found = [history_series(_read_json(r.folder / "history.json")) for r in results.runs_of(scene, method)]
            found = [f for f in found if f is not None]
            if found:
                key = found[0][0]
                curves[method] = (key, [_smooth(s, v) for k, s, v in found if k == key])
        if curves:
            panels.append((scene, curves))
    if not panels:
        return None
    colours = _method_colours(results.methods)
    figure = _new_figure(5.2 * len(panels), 3.8)
    axes = np.atleast_1d(figure.subplots(1, len(panels)))
    add_at = results.config.get("add_at_step")
    for ax, (scene, curves) in zip(axes, panels):
        for method, (key, series) in curves.items():
            grid, median, q1, q3 = _median_curve(series)
            ax.plot(grid, median, color=colours[method], label=method, linewidth=1.4)
            ax.fill_between(grid, q1, q3, color=colours[method], alpha=0.15, linewidth=0)
        keys = {key for key, _ in curves.values()}
        ax.set_ylabel(" / ".join(HISTORY_LABELS[k] for k in sorted(keys)))
        if keys & {"loss", "train_loss"}:
            ax.set_yscale("log")
        if add_at is not None:
            ax.axvline(add_at, color="0.3", linestyle="--", linewidth=1)
            ax.text(add_at, 0.02, " views added", transform=ax.get_xaxis_transform(), fontsize=8, va="bottom",
                    color="0.3")
        ax.set_xlabel("step")
        ax.set_title(scene, fontsize=10)
        ax.grid(alpha=0.3)
    # One legend for all panels, below them, so it never hides a curve.
    legend = {label: handle for ax in axes for handle, label in zip(*ax.get_legend_handles_labels())}
    figure.legend(legend.values(), legend.keys(), loc="upper center", bbox_to_anchor=(0.5, 0.0),
                  ncol=min(4, len(legend)), fontsize=8, frameon=False)
    figure.suptitle("Training curves: median over trials, IQR shaded", fontsize=11, y=1.03)
    return _save(figure, path)


@dataclass
class Figures:
    """The report's figures by scene (an absent key: nothing to draw)."""

    boxplots: dict[str, Path] = field(default_factory=dict)
    maps: dict[str, list[Path]] = field(default_factory=dict)
    map_notes: dict[str, list[str]] = field(default_factory=dict)
    renders: dict[str, Path] = field(default_factory=dict)
    curves: Path | None = None

    def paths(self) -> list[Path]:
        found = [*self.boxplots.values(), *(p for ps in self.maps.values() for p in ps), *self.renders.values()]
        return found + ([self.curves] if self.curves else [])


def make_figures(results: Results) -> Figures:
    folder = results.root / "figures"
    figures = Figures()
    for scene in results.scenes:
        slug = _slug(scene)
        if (path := plot_boxplots(results, scene, folder / f"fig4_boxplots_{slug}.png")) is not None:
            figures.boxplots[scene] = path
        maps, notes = plot_uncertainty_maps(results, scene, folder)
        if maps:
            figures.maps[scene], figures.map_notes[scene] = maps, notes
        if (path := plot_render_grid(results, scene, folder / f"fig3_renders_{slug}.png")) is not None:
            figures.renders[scene] = path
    figures.curves = plot_training_curves(results, folder / "training_curves.png")
    return figures


def figure_sections(results: Results, figures: Figures) -> list[Block]:
    blocks: list[Block] = []
    if figures.maps:
        blocks.append(Heading("Uncertainty over the hemisphere (Fig. 1)"))
        blocks.append(Paragraph("Each method's scores over the candidate views (its first trial), seen from above: "
                                "the centre is straight above the object, the rim the horizon; bright = uncertain "
                                "(min-max normalised per panel). Triangles: the initial views; stars: the views "
                                "the method chose."))
    for scene, paths in figures.maps.items():
        blocks += [Figure(p, f"Fig. 1 ({scene}): uncertainty maps per method") for p in paths]
        blocks += [Paragraph(note) for note in figures.map_notes.get(scene, [])]
    if figures.renders:
        blocks.append(Heading("Test renders (Fig. 3)"))
        blocks += [Figure(p, f"Fig. 3 ({scene}): test renders after training, ground truth on top, one row per "
                             "method (its first trial)") for scene, p in figures.renders.items()]
    if figures.curves is not None:
        blocks += [Heading("Training curves"), Figure(figures.curves, "Training curves: median over trials per "
                                                      "method, IQR shaded; the dashed line marks the step where the "
                                                      "chosen views were added.")]
    return blocks


# ----------------------------------------------------------------------------- entry point


def build_report(results: Results, figures: Figures) -> list[Block]:
    blocks = header_section(results) + summary_section(results)
    for scene in results.scenes:
        blocks += scene_section(results, scene, figures.boxplots.get(scene))
    blocks += table_i_section(results) + table_ii_section(results)
    blocks += figure_sections(results, figures) + timing_section(results) + problems_section(results)
    return blocks


def write_report(results_dir: Path) -> list[Path]:
    """Write `report.md`, a self-contained `report.html` and the figures (`figures/*.png`) for a
    results folder written by `nerfaug run`.

    Args:
        results_dir: the folder holding sweep.json and runs/<scene>/<method>/trial_<k>/.

    Returns:
        The paths written: report.md, report.html, then the figures.

    Raises:
        ReportError: no readable sweep.json in `results_dir`.
    """
    results = collect_results(results_dir)
    figures = make_figures(results)
    blocks = build_report(results, figures)
    root = results.root
    markdown, page = root / "report.md", root / "report.html"
    atomic_write_bytes(markdown, to_markdown(blocks, root).encode())
    atomic_write_bytes(page, to_html(blocks, f"nerfaug report: {root.name}").encode())
    return [markdown, page] + figures.paths()


__all__ = [
    "NotAggregated", "ReportError", "Results", "Run", "collect_results", "history_series", "write_report",
]
