"""The run-folder contract: the files one run writes, named once, with typed readers and writers.

The writer (`experiment.protocol.run_trial`), the reader (`nerfaug.report.collect`) and the tests'
fake writer all go through this module, so a file's name or layout changes in one place::

    runs/<scene>/<method>/trial_<k>/
      result.json      written last: the run is complete iff it exists and is valid (`store`)
      selection.json   the chosen views, every candidate's score and pose, the training poses
      metrics.json     per-view and mean test metrics (`EvaluationResult.to_dict()`)
      history.json     the trainer's per-step records
      config.json      {"experiment": ExperimentConfig, "engine": NerfConfig}
      progress.json    {"step": k}, rewritten while training (for progress displays)
      error.json       {"error": one line, "traceback": ...} when the run failed
      renders/         <i>_render.png and <i>_render_vs_gt.png of the first test views
      uncertainty.png  the selection's scores over the hemisphere
      view_uncertainty/  the first test view after training, as .npy arrays: render.npy (H, W, 3)
                       float16, error.npy (H, W) squared error per pixel (mean over colours),
                       entropy.npy (H, W) ray entropy in bits, fisher.npy (h, w) FisherRF score per
                       pixel at a lower resolution; absent in runs made before it was written

Readers return None for a file that is absent or unreadable: a run folder is read from disk that
another process may be writing, and the report lists such runs rather than failing.
"""

from __future__ import annotations

import io
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from nerfaug import runfiles
from nerfaug.experiment.store import RESULT_FILE, read_result, write_result
from nerfaug.hemisphere import angles_from_pose
from nerfaug.registry import check_name


@dataclass(frozen=True)
class RunFiles:
    """The names of a run folder's files (one instance, `FILES`)."""

    result: str = RESULT_FILE
    selection: str = "selection.json"
    history: str = "history.json"
    metrics: str = "metrics.json"
    config: str = "config.json"
    progress: str = "progress.json"
    error: str = "error.json"
    renders: str = "renders"
    uncertainty: str = "uncertainty.png"
    view_uncertainty: str = "view_uncertainty"


FILES = RunFiles()
SELECTION_KEYS = ("candidate_poses", "scores", "train_poses")
"""What a selection.json needs to be drawn on the hemisphere."""


@dataclass(frozen=True)
class SelectionRecord:
    """A run's selection.json, typed.

    Attributes:
        method: the selection method's name.
        indices: the chosen candidates, in order of choice.
        scores: array (C,), each candidate's score.
        candidate_poses: array (C, 4, 4), camera-to-world.
        train_poses: array (T, 4, 4), the views trained on before the selection.
        chosen_poses: array (k, 4, 4), or None when the file has none.
        raw: the whole JSON object (components, names, angles).
    """

    method: str
    indices: list[int]
    scores: np.ndarray
    candidate_poses: np.ndarray
    train_poses: np.ndarray
    chosen_poses: np.ndarray | None
    raw: dict


def _read_json(folder: Path, name: str):
    """The JSON in `name` of the run folder, None when absent or unreadable; `PathRefused` (never
    None) when it leads outside the run folder: a planted link is refused, not taken for absent."""
    path = runfiles.path_in(folder, name)
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def write_selection(folder: Path, selection: dict, chosen_names: list[str], candidate_poses, train_poses) -> Path:
    """Write selection.json.

    Args:
        selection: `Selection.to_dict()` (method, indices, scores, components, ...).
        chosen_names: the dataset's names of the chosen views.
        candidate_poses: Tensor or array (C, 4, 4), the pool the indices point into.
        train_poses: Tensor or array (T, 4, 4), the views trained on before the selection.
    """
    candidates = torch.as_tensor(
        np.asarray(candidate_poses) if not torch.is_tensor(candidate_poses) else candidate_poses
    )
    chosen = [int(i) for i in selection["indices"]]
    azimuth, polar, _ = angles_from_pose(candidates)
    path = runfiles.write_json(
        folder,
        FILES.selection,
        {
            **selection,
            "chosen_names": list(chosen_names),
            "chosen_poses": candidates[chosen].tolist(),
            "candidate_poses": candidates.tolist(),
            "candidate_azimuth": azimuth.tolist(),
            "candidate_polar": polar.tolist(),
            "train_poses": np.asarray(train_poses).tolist(),
        },
    )
    return path


def read_selection(folder: Path) -> SelectionRecord | None:
    """selection.json as a `SelectionRecord`; None if absent, unreadable or lacking SELECTION_KEYS."""
    raw = _read_json(folder, FILES.selection)
    if not isinstance(raw, dict) or not set(SELECTION_KEYS) <= raw.keys():
        return None
    try:
        chosen = raw.get("chosen_poses")
        return SelectionRecord(
            method=str(raw.get("method", "")),
            indices=[int(i) for i in raw.get("indices", [])],
            scores=np.asarray(raw["scores"], dtype=np.float64).reshape(-1),
            candidate_poses=np.asarray(raw["candidate_poses"], dtype=np.float64).reshape(-1, 4, 4),
            train_poses=np.asarray(raw["train_poses"], dtype=np.float64).reshape(-1, 4, 4),
            chosen_poses=np.asarray(chosen, dtype=np.float64).reshape(-1, 4, 4) if chosen else None,
            raw=raw,
        )
    except (TypeError, ValueError):  # ragged or non-numeric lists
        return None


def write_metrics(folder: Path, metrics: dict) -> Path:
    """Write metrics.json (`EvaluationResult.to_dict()`)."""
    path = runfiles.write_json(folder, FILES.metrics, metrics)
    return path


def read_metrics(folder: Path) -> dict | None:
    found = _read_json(folder, FILES.metrics)
    return found if isinstance(found, dict) else None


def write_history(folder: Path, history) -> Path:
    """Write history.json: a list of per-step records, or a dict of equal-length lists."""
    path = runfiles.write_json(folder, FILES.history, history)
    return path


def read_history(folder: Path) -> list | dict | None:
    found = _read_json(folder, FILES.history)
    return found if isinstance(found, (list, dict)) else None


def write_config(folder: Path, experiment: dict, engine: dict, **extra) -> Path:
    """Write config.json: the experiment's and the engine's settings as dicts, and any `extra`
    entries (e.g. the device the run used)."""
    path = runfiles.write_json(folder, FILES.config, {"experiment": experiment, "engine": engine, **extra})
    return path


def read_config(folder: Path) -> dict | None:
    found = _read_json(folder, FILES.config)
    return found if isinstance(found, dict) else None


def write_progress(folder: Path, step: int) -> Path:
    path = runfiles.write_json(folder, FILES.progress, {"step": int(step)})
    return path


def read_progress(folder: Path) -> int | None:
    """The last step recorded in progress.json, or None."""
    found = _read_json(folder, FILES.progress)
    step = found.get("step") if isinstance(found, dict) else None
    return int(step) if isinstance(step, (int, float)) and not isinstance(step, bool) else None


def write_error(folder: Path, error: str, traceback: str = "") -> Path:
    """Write error.json: why the run failed (one line) and its traceback."""
    path = runfiles.write_json(folder, FILES.error, {"error": error, "traceback": traceback})
    return path


def read_error(folder: Path) -> str | None:
    """The one-line reason in error.json, or None."""
    found = _read_json(folder, FILES.error)
    error = found.get("error") if isinstance(found, dict) else None
    return str(error) if error is not None else None


VIEW_ARRAYS = ("render", "error", "entropy", "fisher")
"""The arrays of `FILES.view_uncertainty`, each `<name>.npy`."""


def write_view_uncertainty(folder: Path, arrays: dict[str, np.ndarray]) -> Path:
    """Write `FILES.view_uncertainty/<name>.npy` for each of `arrays` (names from VIEW_ARRAYS:
    render (H, W, 3), error (H, W), entropy (H, W), fisher (h, w)). Returns the folder."""
    for name in arrays:
        check_name("view array", name, VIEW_ARRAYS)
    for name, values in arrays.items():
        buffer = io.BytesIO()
        np.save(buffer, np.asarray(values), allow_pickle=False)
        runfiles.write_bytes(folder, f"{FILES.view_uncertainty}/{name}.npy", buffer.getvalue())
    return runfiles.path_in(folder, FILES.view_uncertainty)


def read_view_uncertainty(folder: Path) -> dict[str, np.ndarray] | None:
    """The arrays of `FILES.view_uncertainty` by name, as float64; None when the folder is absent
    (runs made before it was written) or render, error or entropy is missing, unreadable or of
    another size. fisher, when absent or unreadable, is left out."""
    if not runfiles.path_in(folder, FILES.view_uncertainty).is_dir():
        return None
    found = {}
    for name in VIEW_ARRAYS:
        try:
            data = runfiles.read_bytes(folder, f"{FILES.view_uncertainty}/{name}.npy")
            found[name] = np.load(io.BytesIO(data), allow_pickle=False).astype(np.float64)
        except (OSError, ValueError):
            continue
    if not {"render", "error", "entropy"} <= found.keys():
        return None
    size = found["render"].shape[:2]
    if found["error"].shape != size or found["entropy"].shape != size or found["render"].shape[2:] != (3,):
        return None
    fisher = found.get("fisher")
    if fisher is not None and (fisher.ndim != 2 or not all(0 < a <= b for a, b in zip(fisher.shape, size))):
        del found["fisher"]
    return found


def render_paths(folder: Path, kind: str = "render") -> list[Path]:
    """The saved test renders, sorted by view: kind "render" (the model's image) or "render_vs_gt"
    (render left, ground truth right)."""
    check_name("render kind", kind, ("render", "render_vs_gt"))
    found = runfiles.path_in(folder, FILES.renders).glob(f"*_{kind}.png")
    return sorted(runfiles.path_in(folder, f"{FILES.renders}/{p.name}") for p in found)


__all__ = [
    "FILES",
    "SELECTION_KEYS",
    "VIEW_ARRAYS",
    "RunFiles",
    "SelectionRecord",
    "read_config",
    "read_error",
    "read_history",
    "read_metrics",
    "read_progress",
    "read_result",
    "read_selection",
    "read_view_uncertainty",
    "render_paths",
    "write_config",
    "write_error",
    "write_history",
    "write_metrics",
    "write_progress",
    "write_result",
    "write_selection",
    "write_view_uncertainty",
]
