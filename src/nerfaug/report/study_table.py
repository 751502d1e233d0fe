"""The study's per-run table: one row per finished run (engine, scene, method, trial, seed, PSNR,
SSIM, LPIPS, the chosen views and their poses, the code version and the run's fingerprint), with
the study's plan, the methods' definitions and each scene's initial views.

It is the study's record: the results page and its figures are generated from this table alone
(`nerfaug.report.study`), so a page committed beside its table can be re-derived without the run
folders, and a study resumes from it (runs recorded with a matching fingerprint are not run
again). Written as JSON, one run per line, rows sorted by (engine, scene, method, trial):

    {"format": "nerfaug-study-table", "version": 1, "plan": {...study.json...},
     "methods": {name: {"label", "description", "definition"}},
     "scenes": {scene: {"initial_poses": [[3x4], ...], "layouts": {"1": [[3x4], ...], ...},
                        "halves": {"0": {"start_deg", "width_deg"}, ...},
                        "test_views": [name, ...], "views": {"test_rule": ..., ...}}},
     "runs": [{"engine", "scene", "method", "trial", "seed", "psnr", "ssim", "lpips",
               "lpips_status", "chosen", "chosen_poses", "code_version", "fingerprint",
               "layout"?, "uniform_fill"?, "curve"?}, ...]}

A scene's `initial_poses` are its first (or only) initial layout's; a study with several layouts
lists the others under `layouts`, and a run started from one of them has its `layout` (absent: 0).
A run whose sampler found fewer positive scores than views to choose has `uniform_fill`: how many
of its views were drawn uniformly (absent: 0). A run that added its views in rounds has `curve`:
its learning curve, [[views in the model, test PSNR], ...] before its first round and after each
(absent for a run of one round).
`halves` gives, per layout, the azimuth window its initial views were taken from; `test_views` and
`views` record which views the runs were scored on and how they were chosen (each absent in tables
of studies run before it was recorded).

Poses are camera-to-world, the top 3x4 rows, rounded to `POSE_DECIMALS` (what the coverage numbers
are computed from, so rounding never separates the table from its page).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from nerfaug.experiment.layout import StudyFolder
from nerfaug.experiment.runfolder import read_selection
from nerfaug.jsonio import atomic_write_bytes
from nerfaug.report.collect import ReportError, Results, Run, collect_results
from nerfaug.report.learning_curve import curve_mean, run_curve

TABLE_FORMAT, TABLE_VERSION = "nerfaug-study-table", 1
POSE_DECIMALS = 6
ROW_FIELDS = (
    "engine",
    "scene",
    "method",
    "trial",
    "seed",
    "psnr",
    "ssim",
    "lpips",
    "lpips_status",
    "chosen",
    "chosen_poses",
    "code_version",
    "fingerprint",
)
OPTIONAL_ROW_FIELDS = ("layout", "uniform_fill", "engine_version", "empty", "curve")
# The reference engine (a run trained alone) has no recorded version: every earlier row is one.
REFERENCE_ENGINE_VERSION = ""


@dataclass(frozen=True)
class RunRow:
    """One finished run of the study.

    Attributes:
        chosen: pool indices of the views the method added, in the order chosen.
        chosen_poses: their camera-to-world poses, top 3x4 rows, as nested lists (k, 3, 4).
        lpips: None where LPIPS was not computed (`lpips_status` says why).
    """

    engine: str
    scene: str
    method: str
    trial: int
    seed: int
    psnr: float
    ssim: float | None
    lpips: float | None
    lpips_status: str
    chosen: list[int]
    chosen_poses: list
    code_version: str
    fingerprint: str
    layout: int = 0
    uniform_fill: int = 0
    engine_version: str = REFERENCE_ENGINE_VERSION
    empty: bool = False
    """Its NeRF rendered its training views as background only (`nerfaug.health`); runs made
    before the check read False."""
    curve: tuple = ()
    """Its learning curve, ((views in the model, test PSNR), ...), views increasing; empty for a
    run of one round (`report.learning_curve.run_curve`)."""

    @property
    def key(self) -> tuple[str, str, str, int]:
        return (self.engine, self.scene, self.method, self.trial)

    def metric(self, name: str) -> float | None:
        return getattr(self, name)

    @property
    def auc(self) -> float | None:
        """The area under its learning curve divided by the span of views (dB: the curve's mean
        height, the rounds study's secondary outcome); None for a run of one round."""
        return curve_mean(self.curve) if len(self.curve) >= 2 else None

    def poses(self) -> np.ndarray:
        """The chosen views' camera-to-world matrices, shape (k, 4, 4)."""
        return homogeneous(self.chosen_poses)


def homogeneous(poses_3x4) -> np.ndarray:
    """(k, 3, 4) nested lists -> (k, 4, 4) float64 camera-to-world matrices."""
    top = np.asarray(poses_3x4, dtype=np.float64).reshape(-1, 3, 4)
    bottom = np.broadcast_to(np.array([0.0, 0.0, 0.0, 1.0]), (top.shape[0], 1, 4))
    return np.concatenate([top, bottom], axis=1)


def rounded_poses(poses) -> list:
    """(k, 4, 4) camera-to-world -> their top 3x4 rows as nested lists, rounded (+ 0.0: no -0.0)."""
    top = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)[:, :3, :]
    return (np.round(top, POSE_DECIMALS) + 0.0).tolist()


def _number(value) -> float | None:
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else None


def row_of(engine: str, run: Run) -> tuple[RunRow, list] | None:
    """A run folder's row and its initial views' poses (3x4 lists); None without a selection
    record (a run of an older nerfaug, or a damaged folder). The row's `layout` is the run's
    initial layout (0 for runs of one layout)."""
    selection = read_selection(run.folder)
    if selection is None or selection.chosen_poses is None:
        return None
    result, metrics = run.result, run.result["metrics"]
    row = RunRow(
        engine=engine,
        scene=run.scene,
        method=run.method,
        trial=run.trial,
        seed=int(result["seed"]),
        psnr=float(metrics["psnr"]),
        ssim=_number(metrics.get("ssim")),
        lpips=_number(metrics.get("lpips")),
        lpips_status=str(result.get("lpips_status", "")),
        chosen=[int(i) for i in result.get("chosen", selection.indices)],
        chosen_poses=rounded_poses(selection.chosen_poses),
        code_version=str(result["code_version"]),
        fingerprint=str(result["fingerprint"]),
        layout=int(result.get("layout", 0)),
        uniform_fill=int(selection.raw.get("uniform_fill", 0)),
        engine_version=str(result.get("engine_version", REFERENCE_ENGINE_VERSION)),
        empty=bool(result.get("health", {}).get("empty", False)),
        curve=tuple((views, psnr) for views, psnr in run_curve(run) or ()),
    )
    return row, rounded_poses(selection.train_poses)


class RunsDisagree(ReportError):
    """A run folder whose initial or test views differ from those of the other runs of its scene,
    or from those the previous table records for it (runs of two versions of a dataset): the table
    holds one set per scene."""


def rows_from_folders(root: Path, engines: list[str]) -> tuple[list[RunRow], dict[str, dict]]:
    """Every valid run under `root/<engine>/` as rows, and what each scene's runs started from
    and were scored on: {scene: {"initial_poses", "layouts"?, "test_views"?, "views"?}}.

    Raises:
        RunsDisagree: two runs of a scene and layout started from different initial views, or two
            runs of a scene were scored on different test views (the table holds one set each).
    """
    rows, scenes = [], {}
    for engine in engines:
        results = StudyFolder(Path(root)).engine(engine)
        if not results.sweep.is_file():
            continue
        for run in collect_results(results.root).runs:
            found = row_of(engine, run)
            if found is None:
                continue
            row, poses = found
            scene = scenes.setdefault(row.scene, {})
            layouts = scene.setdefault("layouts", {})
            if layouts.setdefault(str(row.layout), poses) != poses:
                raise RunsDisagree(f"{run.folder}: its initial views differ from other runs of scene {row.scene!r}")
            views = dict(run.result.get("views", {}))
            half = views.get("half")
            if half is not None and scene.setdefault("halves", {}).setdefault(str(row.layout), half) != half:
                raise RunsDisagree(f"{run.folder}: its initial half differs from other runs of scene {row.scene!r}")
            if "test" in views:
                if scene.setdefault("test_views", views.pop("test")) != run.result["views"]["test"]:
                    raise RunsDisagree(f"{run.folder}: its test views differ from other runs of scene {row.scene!r}")
                views.pop("initial", None)
                scene["views"] = {k: v for k, v in views.items() if k != "half"}
            rows.append(row)
    return rows, {name: scene_record(scene) for name, scene in scenes.items()}


def check_against_table(initial: dict[str, dict], previous: dict | None, path: Path) -> None:
    """Refuse scene records (`initial`, as `rows_from_folders` gives them) that disagree with what
    the table at `path` (`previous`) records for their scene: other test views, or other initial
    views or half for a layout it has. A layout the table has not seen is new, and a field it
    lacks (a table of an older nerfaug) is not compared.

    Raises:
        RunsDisagree: naming the scene, the table and its field.
    """
    for scene, record in initial.items():
        recorded = (previous or {}).get("scenes", {}).get(scene)
        found = _disagreement(record, recorded) if isinstance(recorded, dict) else None
        if found is not None:
            what, field = found
            raise RunsDisagree(
                f"scene {scene!r}: the runs' {what} from those the table records ({path}: scenes.{scene}.{field})"
            )


def _disagreement(record: dict, recorded: dict) -> tuple[str, str] | None:
    """(what differs, the table's field) between a scene's record from its runs and the table's."""
    if "test_views" in record and "test_views" in recorded and record["test_views"] != recorded["test_views"]:
        return "test views differ", "test_views"
    had = initial_poses_by_layout(recorded)
    for layout, poses in sorted(initial_poses_by_layout(record).items()):
        if layout in had and not _same_poses(poses, had[layout]):
            return "initial views differ", "initial_poses" if layout == 0 else f"layouts.{layout}"
    had_halves = halves_by_layout(recorded)
    for layout, half in sorted(halves_by_layout(record).items()):
        if layout in had_halves and not _same_half(half, had_halves[layout]):
            return "initial half differs", f"halves.{layout}"
    return None


def _same_poses(a: list, b: list) -> bool:
    """Poses equal up to the table's rounding: both sides are rounded to `POSE_DECIMALS`, so one
    computed from a float a few bits apart can land a unit of the last decimal away; another
    version of a dataset moves them far more."""
    try:
        a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    except (TypeError, ValueError):  # not numbers, or ragged: not the runs' poses either
        return False
    return a.shape == b.shape and bool(np.allclose(a, b, rtol=0.0, atol=10.0 ** (1 - POSE_DECIMALS)))


def _same_half(a: dict, b: dict) -> bool:
    if not isinstance(a, dict) or not isinstance(b, dict) or a.keys() != b.keys():
        return a == b
    return all(
        math.isclose(a[k], b[k], rel_tol=1e-9, abs_tol=1e-9)
        if _number(a[k]) is not None and _number(b[k]) is not None
        else a[k] == b[k]
        for k in a
    )


def scene_record(found: dict) -> dict:
    """A scene's entry in the table: layout 0's initial poses as `initial_poses` (as tables of
    one layout have always had), the other layouts under `layouts`."""
    layouts = dict(found.pop("layouts"))
    record = {"initial_poses": layouts.pop("0", None)}
    if record["initial_poses"] is None:  # a sitting that ran no trial of layout 0
        record.pop("initial_poses")
    if layouts:
        record["layouts"] = dict(sorted(layouts.items()))
    if "halves" in found:
        found["halves"] = dict(sorted(found["halves"].items()))
    return record | found


def halves_by_layout(scene: dict) -> dict[int, dict]:
    """A table scene entry's initial half per layout ({"start_deg", "width_deg"}), where recorded."""
    return {int(k): v for k, v in scene.get("halves", {}).items()}


def initial_poses_by_layout(scene: dict) -> dict[int, list]:
    """A table scene entry's initial poses per layout (3x4 lists)."""
    found = {int(k): v for k, v in scene.get("layouts", {}).items()}
    if "initial_poses" in scene:
        found[0] = scene["initial_poses"]
    return found


def row_dict(row: RunRow) -> dict:
    """A row as the table stores it: `layout`, `uniform_fill` and `engine_version` only where they
    are not their defaults, so tables of one layout, whose methods always chose by their scores,
    trained by the reference engine, read as they always have."""
    record = asdict(row)
    record["curve"] = [list(point) for point in record["curve"]]
    for optional in OPTIONAL_ROW_FIELDS:
        if record[optional] in (RunRow.__dataclass_fields__[optional].default, []):
            del record[optional]
    return record


def make_table(
    plan: dict,
    rows: list[RunRow],
    initial: dict[str, dict],
    previous: dict | None = None,
    method_records: dict[str, dict] | None = None,
) -> dict:
    """The table of `rows` over `previous`, with `plan`, the methods' records and the scenes'
    records (`initial`, as `rows_from_folders` gives them: initial views per layout, test views).
    A row replaces the previous row of its run; where `rows` hold an (engine, method) with another
    fingerprint than the previous rows of it (its settings or its engine changed), those previous
    rows are dropped: a cell never mixes runs of two configurations.

    `method_records` maps method names to their {"label", "description", "definition"} (the
    method registry's, given by the caller); the table records those of the plan's and the rows'
    methods, over the previous table's records."""
    current = {(row.engine, row.method): row.fingerprint for row in rows}
    kept = [
        row
        for row in (table_rows(previous) if previous else [])
        if current.get((row.engine, row.method), row.fingerprint) == row.fingerprint
    ]
    by_key = {row.key: row for row in kept}
    by_key.update({row.key: row for row in rows})
    scenes = dict((previous or {}).get("scenes", {}))
    for scene, record in initial.items():
        merged = dict(scenes.get(scene, {}))
        for merged_by_layout in ("layouts", "halves"):
            merged[merged_by_layout] = {**merged.get(merged_by_layout, {}), **record.get(merged_by_layout, {})}
        merged.update({k: v for k, v in record.items() if k not in ("layouts", "halves")})
        for merged_by_layout in ("layouts", "halves"):
            if not merged[merged_by_layout]:
                del merged[merged_by_layout]
        scenes[scene] = merged
    ordered = sorted(by_key.values(), key=lambda r: r.key)
    methods = list(dict.fromkeys([*plan.get("methods", []), *(r.method for r in ordered)]))
    return {
        "format": TABLE_FORMAT,
        "version": TABLE_VERSION,
        "plan": plan,
        "methods": {
            **(previous or {}).get("methods", {}),
            **{name: record for name in methods if (record := (method_records or {}).get(name)) is not None},
        },
        "scenes": dict(sorted(scenes.items())),
        "runs": [row_dict(row) for row in ordered],
    }


def table_rows(table: dict) -> list[RunRow]:
    return [_row(run) for run in table["runs"]]


def _row(run: dict) -> RunRow:
    """A table's run as a row, its curve as tuples (a row is frozen: hashable to the last field)."""
    return RunRow(**run | {"curve": tuple(tuple(point) for point in run.get("curve", ()))})


def table_bytes(table: dict) -> bytes:
    """The table as JSON text: the header keys on their own lines, one run per line (diffs
    between sittings stay readable)."""
    head = {k: v for k, v in table.items() if k != "runs"}
    lines = ["{"]
    for key, value in head.items():
        lines.append(f"{json.dumps(key)}: {json.dumps(value, sort_keys=True)},")
    runs = [json.dumps(run, separators=(",", ":")) for run in table["runs"]]
    lines.append('"runs": [')
    lines += [f"{run}," for run in runs[:-1]] + runs[-1:]
    lines += ["]", "}"]
    return ("\n".join(lines) + "\n").encode()


def write_table(path: Path, table: dict) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, table_bytes(table))
    return path


def _refuse(path: Path, where: str, problem: str) -> ReportError:
    return ReportError(f"{path}: {where}: {problem}")


def _check_row(path: Path, index: int, run) -> RunRow:
    where = f"runs[{index}]"
    if not isinstance(run, dict):
        raise _refuse(path, where, "not an object")
    missing = [k for k in ROW_FIELDS if k not in run]
    unknown = sorted(set(run) - set(ROW_FIELDS) - set(OPTIONAL_ROW_FIELDS))
    if missing or unknown:
        raise _refuse(path, where, f"missing {missing}" if missing else f"unknown fields {unknown}")
    for name, kinds in (
        ("engine", str),
        ("scene", str),
        ("method", str),
        ("trial", int),
        ("seed", int),
        ("layout", int),
        ("uniform_fill", int),
        ("engine_version", str),
        ("empty", bool),
    ):
        if name not in run:  # an optional field
            continue
        if not isinstance(run[name], kinds) or (isinstance(run[name], bool) and kinds is not bool):
            raise _refuse(path, f"{where}.{name}", f"{run[name]!r} is not a {kinds.__name__}")
    for name in ("psnr", "ssim", "lpips"):
        value = run[name]
        if value is None and name != "psnr":
            continue
        # PSNR may be inf (identical images); SSIM and LPIPS are finite or null.
        if _number(value) is None or math.isnan(value) or (name != "psnr" and math.isinf(value)):
            raise _refuse(path, f"{where}.{name}", f"{value!r} is not a number")
    try:
        poses = np.asarray(run["chosen_poses"], dtype=np.float64).reshape(-1, 3, 4)
    except (TypeError, ValueError):
        raise _refuse(path, f"{where}.chosen_poses", "not a list of 3x4 matrices") from None
    if poses.shape[0] != len(run["chosen"]) or not np.isfinite(poses).all():
        raise _refuse(path, f"{where}.chosen_poses", f"{poses.shape[0]} finite poses expected for {run['chosen']}")
    if "curve" in run and not _is_curve(run["curve"]):
        raise _refuse(path, f"{where}.curve", f"{run['curve']!r} is not [[views, PSNR], ...] with views increasing")
    return _row(run)


def _is_curve(curve) -> bool:
    """[[views, PSNR], ...]: at least two points, views integers increasing, PSNR numbers."""
    if not isinstance(curve, list) or len(curve) < 2:
        return False
    if not all(isinstance(p, list) and len(p) == 2 for p in curve):
        return False
    views = [p[0] for p in curve]
    if not all(isinstance(v, int) and not isinstance(v, bool) for v in views) or views != sorted(set(views)):
        return False
    return all(_number(p[1]) is not None and not math.isnan(p[1]) for p in curve)


def read_table(path: Path) -> dict:
    """A table written by `write_table`, checked: ReportError naming the file, the field and the
    value otherwise."""
    path = Path(path)
    try:
        table = json.loads(path.read_text())
    except OSError as error:
        raise ReportError(f"{path}: not readable ({error.strerror or error})") from None
    except json.JSONDecodeError as error:
        raise ReportError(f"{path}: invalid JSON ({error.msg} at line {error.lineno})") from None
    if not isinstance(table, dict) or table.get("format") != TABLE_FORMAT:
        raise _refuse(
            path, "format", f"not a {TABLE_FORMAT} (got {table.get('format') if isinstance(table, dict) else table!r})"
        )
    if table.get("version") != TABLE_VERSION:
        raise _refuse(path, "version", f"{table.get('version')!r}, this nerfaug reads version {TABLE_VERSION}")
    for key, kind in (("plan", dict), ("methods", dict), ("scenes", dict), ("runs", list)):
        if not isinstance(table.get(key), kind):
            raise _refuse(path, key, f"missing or not a {kind.__name__}")
    keys = set()
    for index, run in enumerate(table["runs"]):
        row = _check_row(path, index, run)
        if row.key in keys:
            raise _refuse(path, f"runs[{index}]", f"a second row for {'/'.join(map(str, row.key))}")
        if row.layout not in initial_poses_by_layout(table["scenes"].get(row.scene, {})):
            raise _refuse(
                path,
                f"runs[{index}].scene",
                f"{row.scene!r} has no initial views of layout {row.layout} under 'scenes'",
            )
        keys.add(row.key)
    return table


def engine_results(table: dict, engine: str) -> Results:
    """One engine's rows as the `Results` the report's figures and paired values read (runs
    without folders: every number comes from the table)."""
    rows = [r for r in table_rows(table) if r.engine == engine]
    runs = [
        Run(
            r.scene,
            r.method,
            r.trial,
            Path("."),
            {"metrics": {"psnr": r.psnr, "ssim": r.ssim, "lpips": r.lpips}, "lpips_status": r.lpips_status}
            | ({"curve": [list(point) for point in r.curve]} if r.curve else {}),
        )
        for r in rows
    ]
    plan = table["plan"]
    scenes = [s for s in plan.get("scenes", []) if any(r.scene == s for r in rows)]
    scenes += sorted({r.scene for r in rows} - set(scenes))
    methods = [m for m in plan.get("methods", []) if any(r.method == m for r in rows)]
    methods += sorted({r.method for r in rows} - set(methods))
    return Results(Path("."), {"config": {"methods": methods}}, runs, [], [], scenes, methods)


__all__ = [
    "RunRow",
    "RunsDisagree",
    "check_against_table",
    "engine_results",
    "homogeneous",
    "halves_by_layout",
    "initial_poses_by_layout",
    "make_table",
    "read_table",
    "row_dict",
    "rows_from_folders",
    "scene_record",
    "write_table",
]
