"""Where things live in the folders the experiments write: the one module that names their files
and subfolders. A results folder (`nerfaug run --out`)::

    RESULTS/
      .nerfaug                         marker: nerfaug made this folder
      sweep.json                       what produced the results (fingerprint checked on re-runs)
      runs/<scene>/<method>/trial_<k>/ one run (its files: `experiment.runfolder.FILES`)
      superseded/<time>/               runs/ and sweep.json moved aside by --force (never deleted)
      datasets/<scene>-<res>px/        a built-in scene rendered for these runs
      datasets/cache/                  downscaled datasets the runs share
      report.md, report.html, figures/ the report

and a study folder (`nerfaug study --out`)::

    STUDY/
      study.json                       the plan: engines run and left out, scenes, methods, trials,
                                       the commands, the machine
      datasets/<res>px/<scene>/        each built-in scene rendered once, shared by every engine
      <engine>/                        a results folder per engine
      study-table.json                 the per-run table (unless --table names another file)
      study.md, figures/               the summary, generated from the table alone

The folders a sweep or a study fills with data (`datasets/`, the cache, an engine's folder) are
named here through `nerfaug.runfiles.checked`: one that leads out of the results or study folder
(a symbolic link planted in place of `datasets/` or `<engine>/`) is refused in one line naming it
(`PathRefused`) before anything is rendered, read or written through it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from nerfaug import runfiles
from nerfaug.containment import is_inside

TRIAL_NAME = re.compile(r"trial_(\d+)")
"""A run folder's name: `trial_<k>`, k the trial."""


@dataclass(frozen=True)
class ResultsFolder:
    """A results folder's paths (`nerfaug run --out`, or one engine of a study).

    Example:
        >>> results = ResultsFolder(Path("results"))
        >>> str(results.run("lego", "ours", 3))
        'results/runs/lego/ours/trial_003'
        >>> str(results.dataset("lego", 100))
        'results/datasets/lego-100px'
    """

    root: Path

    @property
    def sweep(self) -> Path:
        """The sweep record: what produced the results."""
        return self.root / "sweep.json"

    @property
    def runs(self) -> Path:
        return self.root / "runs"

    def run(self, scene: str, method: str, trial: int) -> Path:
        """The folder of one run."""
        return self.runs / scene / method / f"trial_{trial:03d}"

    def run_folders(self) -> list[Path]:
        """Every folder at run depth (`runs/<scene>/<method>/<name>`), finished or not, sorted; one
        that leads out of the results folder (a link) is not one of its runs."""
        return sorted(p for p in self.runs.glob("*/*/*") if p.is_dir() and is_inside(self.root, p))

    @property
    def superseded(self) -> Path:
        """Where --force moves earlier runs (a folder per move, named by the time)."""
        return self.root / "superseded"

    def dataset(self, scene: str, resolution: int) -> Path:
        """Where a built-in scene is rendered for these runs (`PathRefused`: it leads out)."""
        return runfiles.checked(self.root, Path("datasets", f"{scene}-{resolution}px"))

    @property
    def dataset_cache(self) -> Path:
        """Where the runs share their downscaled datasets (`PathRefused`: it leads out)."""
        return runfiles.checked(self.root, Path("datasets", "cache"))

    @property
    def report(self) -> tuple[Path, Path]:
        """The report: (Markdown, self-contained HTML)."""
        return self.root / "report.md", self.root / "report.html"

    @property
    def figures(self) -> Path:
        return self.root / "figures"


@dataclass(frozen=True)
class StudyFolder:
    """A study folder's paths (`nerfaug study --out`).

    Example:
        >>> study = StudyFolder(Path("study"))
        >>> str(study.engine("cpu").sweep), str(study.dataset(100, "lego"))
        ('study/cpu/sweep.json', 'study/datasets/100px/lego')
    """

    root: Path

    @property
    def record(self) -> Path:
        """The plan of every sitting (study.json)."""
        return self.root / "study.json"

    @property
    def table(self) -> Path:
        """The per-run table, where --table names no other file."""
        return self.root / "study-table.json"

    @property
    def summary(self) -> Path:
        return self.root / "study.md"

    @property
    def figures(self) -> Path:
        return self.root / "figures"

    def engine(self, name: str) -> ResultsFolder:
        """The results folder of one engine's runs (`PathRefused`: it leads out of the study folder)."""
        return ResultsFolder(runfiles.checked(self.root, name))

    def dataset(self, resolution: int, scene: str) -> Path:
        """Where a built-in scene is rendered once for every engine (named by the scene, so results
        and per-scene settings know it by its name; `PathRefused`: it leads out)."""
        return runfiles.checked(self.root, Path("datasets", f"{resolution}px", scene))
