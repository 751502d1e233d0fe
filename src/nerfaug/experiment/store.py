"""The results folder: one folder per run, written so that a crash never leaves a half-run that
looks complete.

Layout::

    RESULTS/
      sweep.json                       what produced the results (fingerprint checked on re-runs)
      datasets/<scene>/                the scene's Blender-format dataset (rendered once)
      runs/<scene>/<method>/trial_<k>/
        config.json  selection.json  metrics.json  history.json  renders/*.png
        result.json                    written last: the run is complete iff it exists and is valid

Every file is written to a temporary name and renamed into place (atomic on POSIX).
"""

from __future__ import annotations

import hashlib
import json
import shutil
from dataclasses import dataclass
from pathlib import Path

from nerfaug.data.frames import atomic_write_json

RESULT_FILE = "result.json"
RESULT_KEYS = ("scene", "method", "trial", "seed", "fingerprint", "metrics", "timing")


@dataclass(frozen=True)
class RunKey:
    """Which run: a (scene, method, trial) cell of the sweep."""

    scene: str
    method: str
    trial: int

    def folder(self, root: Path) -> Path:
        return Path(root) / "runs" / self.scene / self.method / f"trial_{self.trial:03d}"

    def __str__(self) -> str:
        return f"{self.scene}/{self.method}/trial {self.trial}"


def fingerprint(config: dict) -> str:
    """A short stable hash of the parts of a config that change results."""
    return hashlib.sha256(json.dumps(config, sort_keys=True, default=str).encode()).hexdigest()[:16]


def read_result(folder: Path, expected_fingerprint: str | None = None) -> dict | None:
    """The run's result if the run is complete and valid, else None.

    Invalid means: unreadable or truncated JSON, missing keys, non-finite metrics, or a
    fingerprint that differs from the sweep's (the run was made with another config).
    """
    path = Path(folder) / RESULT_FILE
    try:
        result = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return None
    if not isinstance(result, dict) or any(key not in result for key in RESULT_KEYS):
        return None
    if expected_fingerprint is not None and result["fingerprint"] != expected_fingerprint:
        return None
    metrics = result["metrics"]
    if not isinstance(metrics, dict) or not isinstance(metrics.get("psnr"), (int, float)):
        return None
    return result


def clear_incomplete(folder: Path) -> bool:
    """Remove a run folder that has no valid result (a crash or a corrupted file). Returns whether
    anything was removed."""
    folder = Path(folder)
    if folder.exists():
        shutil.rmtree(folder)
        return True
    return False


def write_result(folder: Path, result: dict) -> None:
    """Mark a run complete. Call only after every other file of the run is written."""
    missing = [key for key in RESULT_KEYS if key not in result]
    if missing:
        raise ValueError(f"result is missing {missing}")
    atomic_write_json(Path(folder) / RESULT_FILE, result)


class IncompatibleResults(RuntimeError):
    """The results folder holds runs made with a different configuration."""


def check_sweep(root: Path, sweep: dict, force: bool = False) -> None:
    """Record the sweep's config in `root/sweep.json`, refusing to mix incompatible results.

    Settings that change results (everything in `sweep["fingerprinted"]`) must match the folder's;
    the list of scenes, methods and trials may grow (new runs are added beside old ones).
    """
    root = Path(root)
    path = root / "sweep.json"
    if path.exists() and not force:
        try:
            previous = json.loads(path.read_text())
        except json.JSONDecodeError:
            previous = None
        if previous is not None and previous.get("fingerprint") != sweep["fingerprint"]:
            old, new = previous.get("fingerprinted", {}), sweep["fingerprinted"]
            changed = sorted(k for k in set(old) | set(new) if old.get(k) != new.get(k))
            details = "; ".join(f"{k}: {old.get(k)!r} -> {new.get(k)!r}" for k in changed[:6])
            raise IncompatibleResults(
                f"{path}: results there were made with a different configuration ({details}). "
                "Use another --out folder, or --force to discard them and start again."
            )
    if force and (root / "runs").exists():
        shutil.rmtree(root / "runs")
    atomic_write_json(path, sweep)
