"""A session's state, as `session.json` holds it: typed, validated on reading, and every path in
it checked to stay inside the run folder.

The file's layout (format 1) is unchanged from before the typed state: the same 17 keys, so files
written by earlier versions load, and earlier versions can read the files written now. One optional
key was added since, `integrity` (`Integrity`): earlier versions ignore it, and a file without it
is checked from its next save on.
"""

from __future__ import annotations

import datetime
import json
import math
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path, PurePosixPath

import nerfaug
from nerfaug.data.format import Format
from nerfaug.data.formats import FORMATS
from nerfaug.data.frame import Hemisphere
from nerfaug.errors import NerfaugError

SESSION_FORMAT = 1
# The run folder's names (the layout is drawn in `nerfaug.capture.session`).
SESSION_FILE = "session.json"
CHECKPOINT_FILE = "checkpoint.pt"
DATASET_DIR = "dataset"
PROPOSALS_DIR = "proposals"
# Marker kinds (`nerfaug.owned`): the run folder, its dataset copy, and a folder `export` wrote.
RUN_KIND, DATASET_KIND, EXPORT_KIND = "capture-session", "capture-dataset", "capture-export"
# The split the run's dataset copy holds the views in, whatever the source's split was.
DATASET_SPLIT = "train"


class SessionError(NerfaugError, RuntimeError):
    """A run folder is missing, incomplete or inconsistent; the message says which file and why."""


class DuplicateViews(UserWarning):
    """The same view (camera pose) twice in a dataset or an addition; the message names the frames."""


class UnverifiedCheckpoint(UserWarning):
    """A checkpoint that session.json records no digest of (a session saved before digests were
    kept) is used; the message names it. Its digest is recorded at the next save."""


def now() -> str:
    return datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")


@dataclass
class SourceInfo:
    """The dataset a session was started from (provenance; `export` takes its val/test splits)."""

    data_dir: str
    split: str
    format: str


@dataclass
class DatasetInfo:
    """The run's own copy of the dataset: `run/dataset/<json>` with images in `run/dataset/<folder>`."""

    format: str
    folder: str
    json: str

    @classmethod
    def of(cls, fmt: Format) -> DatasetInfo:
        """The names a copy in `fmt` has (recorded so that every version can read the folder)."""
        return cls(fmt.name, fmt.image_folder(DATASET_SPLIT), fmt.listing(Path(), DATASET_SPLIT).name)


@dataclass
class Intrinsics:
    """The dataset's camera, full resolution (pixels)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    camera_angle_x: float


@dataclass
class ProposalRecord:
    """One `propose` call, as kept in the history. Keys a later version adds are kept in `extra`."""

    number: int
    method: str
    n: int
    step: int
    seed: int | None
    candidates: str
    n_candidates: int
    names: list[str]
    poses: list
    azimuth: list[float]
    polar: list[float]
    file: str
    created: str
    extra: dict = field(default_factory=dict)


@dataclass
class AdditionRecord:
    """One `add_views` call: the new frames' names and the proposal they answer (or None)."""

    step: int
    names: list[str]
    proposal: int | None
    created: str
    extra: dict = field(default_factory=dict)


@dataclass
class Integrity:
    """What the session wrote, by content (sha256 hex digests), so that `open` can tell its own
    files from files replaced, edited or deleted since.

    Attributes:
        checkpoint: digest of the checkpoint last saved (None: not recorded yet).
        pending: digest of a checkpoint being saved: `save` records it before writing the file, so
            a process killed between the two writes leaves a checkpoint the session still knows.
        captures: each frame's `file_path` -> digest of its image in the run's dataset.
    """

    checkpoint: str | None = None
    pending: str | None = None
    captures: dict[str, str] = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"checkpoint": self.checkpoint, "pending": self.pending, "captures": dict(self.captures)}


@dataclass
class SessionState:
    """Everything `session.json` records about a session besides the checkpoint."""

    source: SourceInfo
    dataset: DatasetInfo
    preset: str
    engine: dict
    seed: int
    downscale: int
    background: tuple[float, float, float]
    intrinsics: Intrinsics
    hemisphere: Hemisphere
    hemisphere_estimated: dict[str, bool]
    step: int = 0
    views_in_model: int = 0
    proposals: list[ProposalRecord] = field(default_factory=list)
    additions: list[AdditionRecord] = field(default_factory=list)
    format: int = SESSION_FORMAT
    nerfaug: str = nerfaug.__version__
    created: str = field(default_factory=now)
    saved: str | None = None
    integrity: Integrity = field(default_factory=Integrity)

    def to_dict(self) -> dict:
        """The JSON object written to session.json (the historic key layout)."""
        data = {
            "format": self.format,
            "nerfaug": self.nerfaug,
            "created": self.created,
            "source": asdict(self.source),
            "dataset": asdict(self.dataset),
            "preset": self.preset,
            "engine": self.engine,
            "seed": self.seed,
            "downscale": self.downscale,
            "background": list(self.background),
            "intrinsics": asdict(self.intrinsics),
            "hemisphere": self.hemisphere.to_dict(),
            "hemisphere_estimated": dict(self.hemisphere_estimated),
            "step": self.step,
            "views_in_model": self.views_in_model,
            "proposals": [_record_dict(p) for p in self.proposals],
            "additions": [_record_dict(a) for a in self.additions],
        }
        if self.saved is not None:
            data["saved"] = self.saved
        if self.integrity.checkpoint is not None or self.integrity.captures:
            data["integrity"] = self.integrity.to_dict()
        return data

    @classmethod
    def from_dict(cls, data, path: Path) -> SessionState:
        """Parse and validate a session.json object.

        Raises:
            SessionError: naming `path`, the field and the value that is missing or wrong.
        """
        reader = _Reader(path)
        if not isinstance(data, dict):
            raise SessionError(f"{path}: expected a JSON object at the top level, got {type(data).__name__}")
        if data.get("format") != SESSION_FORMAT:
            raise SessionError(
                f"{path}, field 'format': unsupported session format (got {data.get('format')!r}); "
                f"this nerfaug reads format {SESSION_FORMAT}"
            )
        source = reader.section(data, "source", SourceInfo, {"data_dir": str, "split": str, "format": str})
        dataset = reader.section(data, "dataset", DatasetInfo, {"format": str, "folder": str, "json": str})
        if dataset.format not in FORMATS:
            reader.fail("dataset.format", dataset.format, f"must be one of {tuple(FORMATS)}")
        expected = DatasetInfo.of(FORMATS[dataset.format])
        for key in ("folder", "json"):
            reader.relative_name(f"dataset.{key}", getattr(dataset, key))
            if getattr(dataset, key) != getattr(expected, key):
                reader.fail(
                    f"dataset.{key}",
                    getattr(dataset, key),
                    f"the {dataset.format} format names it {getattr(expected, key)!r}",
                )
        intrinsics = reader.section(
            data,
            "intrinsics",
            Intrinsics,
            {"width": int, "height": int, "fx": float, "fy": float, "cx": float, "cy": float, "camera_angle_x": float},
        )
        if intrinsics.width < 1 or intrinsics.height < 1:
            reader.fail("intrinsics", [intrinsics.width, intrinsics.height], "the image size must be positive")
        try:
            hemisphere = Hemisphere.from_dict(reader.get(data, "hemisphere", dict))
        except (KeyError, TypeError, ValueError) as error:
            reader.fail("hemisphere", data.get("hemisphere"), f"not a valid hemisphere ({error})")
        background = reader.get(data, "background", list)
        if len(background) != 3 or not all(_number(c) and 0 <= c <= 1 for c in background):
            reader.fail("background", background, "must be three numbers in [0, 1]")
        seed, downscale = reader.get(data, "seed", int), reader.get(data, "downscale", int)
        if seed < 0 or downscale < 1:
            reader.fail("seed/downscale", [seed, downscale], "seed must be >= 0 and downscale >= 1")
        proposals = [
            reader.record(p, f"proposals[{i}]", ProposalRecord)
            for i, p in enumerate(reader.get(data, "proposals", list))
        ]
        for i, p in enumerate(proposals):
            reader.relative_name(f"proposals[{i}].file", p.file)
        return cls(
            source=source,
            dataset=dataset,
            preset=reader.get(data, "preset", str),
            engine=reader.get(data, "engine", dict),
            seed=seed,
            downscale=downscale,
            background=tuple(float(c) for c in background),
            intrinsics=intrinsics,
            hemisphere=hemisphere,
            hemisphere_estimated=dict(data.get("hemisphere_estimated") or {}),
            step=reader.get(data, "step", int),
            views_in_model=reader.get(data, "views_in_model", int),
            proposals=proposals,
            additions=[
                reader.record(a, f"additions[{i}]", AdditionRecord)
                for i, a in enumerate(reader.get(data, "additions", list))
            ],
            format=SESSION_FORMAT,
            nerfaug=str(data.get("nerfaug", "")),
            created=str(data.get("created", "")),
            saved=data.get("saved"),
            integrity=reader.integrity(data),
        )

    @classmethod
    def read(cls, run_dir: Path) -> SessionState:
        """The state in `run_dir/session.json`.

        Raises:
            SessionError: the file is missing, not JSON, or holds a missing or wrong value.
        """
        path = Path(run_dir) / SESSION_FILE
        if not path.is_file():
            raise SessionError(
                f"{run_dir} is not a capture session: {SESSION_FILE} not found "
                f"(start one with `nerfaug train DATA --out {run_dir}`)"
            )
        try:
            data = json.loads(path.read_text())
        except json.JSONDecodeError as error:
            raise SessionError(f"{path}: invalid JSON at line {error.lineno}: {error.msg}") from None
        except (OSError, UnicodeDecodeError) as error:
            raise SessionError(f"{path}: cannot read: {error}") from None
        return cls.from_dict(data, path)


def _record_dict(record) -> dict:
    data = {f.name: getattr(record, f.name) for f in fields(record) if f.name != "extra"}
    return {**record.extra, **data}


def _number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


class _Reader:
    """Typed access to session.json's fields, failing with the file, the field and the value."""

    def __init__(self, path: Path):
        self.path = path

    def fail(self, name: str, value, problem: str):
        text = repr(value)
        raise SessionError(
            f"{self.path}, field '{name}': {problem} (got {text[:120]}); the file was edited or "
            "damaged: restore it, or start a new session with `nerfaug train DATA --out NEW_RUN`"
        )

    def check(self, name: str, value, kind: type):
        if kind is float and _number(value):
            return float(value)
        if kind is int and isinstance(value, int) and not isinstance(value, bool):
            return value
        if kind is int and isinstance(value, float) and value.is_integer():
            return int(value)
        if kind in (str, dict, list) and isinstance(value, kind):
            return value
        self.fail(name, value, f"expected {kind.__name__}")

    def get(self, data: dict, key: str, kind: type, prefix: str = ""):
        if key not in data:
            self.fail(prefix + key, None, "missing")
        return self.check(prefix + key, data[key], kind)

    def section(self, data: dict, key: str, cls, types: dict[str, type]):
        part = self.get(data, key, dict)
        return cls(**{name: self.get(part, name, kind, f"{key}.") for name, kind in types.items()})

    def record(self, data, name: str, cls):
        if not isinstance(data, dict):
            self.fail(name, data, "expected an object")
        known = {f.name for f in fields(cls)} - {"extra"}
        missing = [k for k in known if k not in data and k not in ("seed", "proposal")]
        if missing:
            self.fail(f"{name}.{missing[0]}", None, "missing")
        values = {k: data.get(k) for k in known}
        extra = {k: v for k, v in data.items() if k not in known}
        return cls(**values, extra=extra)

    def integrity(self, data: dict) -> Integrity:
        """The optional `integrity` section (absent in files of earlier versions)."""
        part = data.get("integrity")
        if part is None:
            return Integrity()
        if not isinstance(part, dict):
            self.fail("integrity", part, "expected an object")
        digests = {k: part.get(k) for k in ("checkpoint", "pending")}
        for key, value in digests.items():
            if value is not None and not isinstance(value, str):
                self.fail(f"integrity.{key}", value, "expected a sha256 digest")
        captures = part.get("captures") or {}
        if not isinstance(captures, dict) or not all(isinstance(v, str) for v in captures.values()):
            self.fail("integrity.captures", captures, "expected an object of file paths to sha256 digests")
        return Integrity(digests["checkpoint"], digests["pending"], dict(captures))

    def relative_name(self, name: str, value: str) -> None:
        """A path the session joins to its run folder: relative, and never leaving it."""
        parts = PurePosixPath(value.replace("\\", "/")).parts
        if not parts or PurePosixPath(value).is_absolute() or Path(value).is_absolute() or ".." in parts:
            self.fail(name, value, "must be a path inside the run folder")
