"""A session's state, as `session.json` holds it: one pydantic model (`SessionState`) that reads,
validates and writes the file, every path in it checked to stay inside the run folder; and what a
session reports of itself (`SessionSummary`).

The file's layout is format 2: format 1's keys, with the engine's name under "engine" (format 1:
"preset"; a preset's name, or {"preset": NAME, GROUP: {SETTING: VALUE}} for the settings changed
over it, as over HTTP) and its complete settings under "engine_config" (format 1: "engine"), so
that the engine and each setting have one name on the command line, over HTTP and here. An earlier
file's flat variant name ("cpu+hidden_dim=48") is read as its settings and written nested. A
format-1 file still loads: its two keys are
renamed when it is read (`SessionState._format_1`, the one place that knows the old names), and it
is written as format 2 at its next save. One optional key, `integrity` (`Integrity`): a file
without it is checked from its next save on. A record's keys that a later version adds are kept
(`model_extra`).
"""

from __future__ import annotations

import datetime
import json
from dataclasses import replace
from pathlib import Path, PurePosixPath
from typing import TYPE_CHECKING, Annotated

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    PlainSerializer,
    PlainValidator,
    ValidationError,
    field_validator,
    model_validator,
)

import nerfaug
from nerfaug import runfiles
from nerfaug.capture.dataset import default_split
from nerfaug.capture.requests import Downscale, Intrinsics, RequestError, Seed, SessionSettings
from nerfaug.capture.runfolder import DATASET_SPLIT, SESSION_FILE
from nerfaug.data.formats import FORMATS, plainest_format
from nerfaug.data.interface import DatasetSplit, Format
from nerfaug.data.world_frame import Hemisphere, pole_is_estimated
from nerfaug.errors import NerfaugError
from nerfaug.nerf.config import NerfConfig
from nerfaug.nerf.engine import Engine

if TYPE_CHECKING:  # cameras bring torch; the state is read without it
    from nerfaug.cameras import Cameras

SESSION_FORMAT = 2
# The engine a session records for a `NerfConfig` given as is (not by a name).
CUSTOM_ENGINE = "custom"


class SessionError(NerfaugError, RuntimeError):
    """A run folder is missing, incomplete or inconsistent; the message says which file and why."""


class DuplicateViews(UserWarning):
    """The same view (camera pose) twice in a dataset or an addition; the message names the frames."""


class TiltedPole(UserWarning):
    """The hemisphere's pole is far from the cameras' mean up axis: the candidate views would lie
    on a tilted hemisphere (a capture whose world is not z-up, given the default pole); the message
    says how to set the pole."""


class UnverifiedCheckpoint(UserWarning):
    """A checkpoint that session.json records no digest of (a session saved before digests were
    kept) is used; the message names it. Its digest is recorded at the next save."""


def now() -> str:
    return datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")


def _inside(value: str) -> str:
    """A path the session joins to its run folder: relative, and never leaving it."""
    parts = PurePosixPath(value.replace("\\", "/")).parts
    if not parts or PurePosixPath(value).is_absolute() or Path(value).is_absolute() or ".." in parts:
        raise ValueError("must be a path inside the run folder")
    return value


InsideRun = Annotated[str, AfterValidator(_inside)]


def _hemisphere(value) -> Hemisphere:
    if isinstance(value, Hemisphere):
        return value
    try:
        return Hemisphere.from_dict(value)
    except (KeyError, TypeError, ValueError) as error:
        raise ValueError(f"not a valid hemisphere ({error})") from None


StoredHemisphere = Annotated[Hemisphere, PlainValidator(_hemisphere), PlainSerializer(Hemisphere.to_dict)]
Unit = Annotated[float, Field(ge=0, le=1)]


class Stored(BaseModel):
    """A part of session.json: non-finite numbers refused, changed in place by the session."""

    model_config = ConfigDict(allow_inf_nan=False)


class SourceInfo(Stored):
    """The dataset a session was started from (provenance; `export` takes its val/test splits)."""

    data_dir: str
    split: str
    format: str


class DatasetInfo(Stored):
    """The run's own copy of the dataset: `run/dataset/<json>` with images in `run/dataset/<folder>`."""

    model_config = ConfigDict(populate_by_name=True)

    format: str
    folder: InsideRun
    listing: InsideRun = Field(alias="json")

    @field_validator("format")
    @classmethod
    def _registered(cls, name: str) -> str:
        if name not in FORMATS:
            raise ValueError(f"must be one of {tuple(FORMATS)}")
        return name

    @model_validator(mode="after")
    def _as_the_format_names_them(self) -> DatasetInfo:
        expected = DatasetInfo.of(FORMATS[self.format])
        for key, name in (("folder", "folder"), ("listing", "json")):
            mine, theirs = getattr(self, key), getattr(expected, key)
            if mine != theirs:
                raise ValueError(f"{name} {mine!r}: the {self.format} format names it {theirs!r}")
        return self

    @classmethod
    def of(cls, fmt: Format) -> DatasetInfo:
        """The names a copy in `fmt` has (recorded so that every version can read the folder)."""
        return cls.model_construct(
            format=fmt.name, folder=fmt.image_folder(DATASET_SPLIT), listing=fmt.listing(Path(), DATASET_SPLIT).name
        )


class Record(Stored):
    """A history record; keys a later version adds are kept."""

    model_config = ConfigDict(extra="allow")


class ProposalRecord(Record):
    """One `propose` call, as kept in the history (with "selection", "constraints",
    "min_separation" and "uniform_fill" among its further keys)."""

    number: int
    method: str
    n: int
    step: int
    seed: int | None = None
    candidates: str
    n_candidates: int
    names: list[str]
    poses: list
    azimuth: list[float]
    polar: list[float]
    file: InsideRun
    created: str


class AdditionRecord(Record):
    """One `add_views` call: the new frames' names and the proposal they answer (or None), with
    "warnings" among its further keys when any were given."""

    step: int
    names: list[str]
    proposal: int | None = None
    created: str

    @property
    def warnings(self) -> list[str]:
        """What was warned about (`DuplicateViews`), one line each."""
        return list((self.model_extra or {}).get("warnings", []))


class Integrity(Stored):
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
    captures: dict[str, str] = Field(default_factory=dict)


class SessionState(Stored):
    """Everything `session.json` records about a session besides the checkpoint."""

    format: int = SESSION_FORMAT
    nerfaug: str = nerfaug.__version__
    created: str = Field(default_factory=now)
    source: SourceInfo
    dataset: DatasetInfo
    engine: str | dict
    """the engine (`Engine.record`: a preset's name, or {"preset": NAME, GROUP: {SETTING: VALUE}}
    with the settings changed over it), or "custom" for a `NerfConfig` given as is."""
    engine_config: dict
    """the engine's complete settings (`NerfConfig.to_dict()`)."""
    seed: Seed
    downscale: Downscale
    background: tuple[Unit, Unit, Unit]
    intrinsics: Intrinsics
    hemisphere: StoredHemisphere
    hemisphere_estimated: dict[str, bool] = Field(default_factory=dict)
    step: int = 0
    views_in_model: int = 0
    proposals: list[ProposalRecord] = Field(default_factory=list)
    additions: list[AdditionRecord] = Field(default_factory=list)
    saved: str | None = None
    integrity: Integrity = Field(default_factory=Integrity)
    start: dict | None = None
    """a sparse start: {"initial", "layout", "of"} views the session started from, of the source's."""
    pool: InsideRun | None = None
    """a sparse start's candidate pool (`POOL_FILE`), where `propose` chooses by default."""

    @model_validator(mode="before")
    @classmethod
    def _format_1(cls, data):
        """A format-1 file's keys as format 2 names them: "preset" -> "engine" (the name), "engine"
        -> "engine_config" (the settings)."""
        if isinstance(data, dict) and data.get("format") == 1 and not isinstance(data.get("format"), bool):
            data = {**data, "format": SESSION_FORMAT}
            data["engine_config"] = data.pop("engine", None)
            data["engine"] = data.pop("preset", None)
        return data

    @field_validator("format", mode="before")
    @classmethod
    def _supported(cls, value) -> int:
        if isinstance(value, bool) or not isinstance(value, int):  # `true` is no format number
            raise ValueError(f"must be a format number ({SESSION_FORMAT})")
        if value != SESSION_FORMAT:
            raise ValueError(f"unsupported session format; this nerfaug reads format {SESSION_FORMAT}")
        return value

    @field_validator("engine")
    @classmethod
    def _known_engine(cls, value: str | dict) -> str | dict:
        """The engine as this format records it: an unknown engine or setting refused, naming
        them; an earlier file's flat variant name ("cpu+hidden_dim=48") read as its settings."""
        return value if value == CUSTOM_ENGINE else Engine.read(value).record()

    def named_engine(self) -> Engine | None:
        """The engine the session trains with, or None for a `NerfConfig` given as is."""
        return None if self.engine == CUSTOM_ENGINE else Engine.read(self.engine)

    @model_validator(mode="after")
    def _engine_is_its_settings(self):
        """The engine's name and its recorded settings agree: a name over another engine's
        settings would be trained as the one and reported as the other."""
        if self.engine == CUSTOM_ENGINE:
            return self
        try:
            recorded = NerfConfig.from_dict(self.engine_config)
        except ValueError as error:
            raise ValueError(f"engine_config: {error}") from None
        named = Engine.read(self.engine).config
        if recorded != named:
            theirs = named.flat()
            differ = ", ".join(sorted(k for k, v in recorded.flat().items() if theirs.get(k, v) != v)[:3])
            raise ValueError(
                f"fields 'engine' and 'engine_config' disagree: engine {self.engine!r} is not the engine "
                f"engine_config holds (they differ in {differ})"
            )
        return self

    def to_dict(self) -> dict:
        """The JSON object written to session.json (the historic key layout)."""
        data = self.model_dump(mode="json", by_alias=True)
        if self.saved is None:
            del data["saved"]
        if self.integrity.checkpoint is None and not self.integrity.captures:
            del data["integrity"]
        for key in ("start", "pool"):
            if data[key] is None:
                del data[key]
        return data

    def settings(self) -> SessionSettings:
        """The settings the session was made with (a centre, radius or pole it estimated: None,
        or `estimate_up`)."""
        h, estimated = self.hemisphere, self.hemisphere_estimated
        return SessionSettings(
            engine=self.named_engine() or self.engine,
            seed=self.seed,
            downscale=self.downscale,
            centre=None if estimated.get("centre", False) else h.centre,
            radius=None if estimated.get("radius", False) else h.radius,
            up=h.up,
            estimate_up=estimated.get("up", False),
        )

    def differences(
        self, settings: SessionSettings, given=None, split: str | None = None, data: str | Path | None = None
    ) -> list[tuple[str, str, str]]:
        """What asks for another session than this one (a session keeps its own settings), each
        as (field, asked, this session's) in words: the dataset folder `data` ("data", first),
        the fields of `settings` named in `given` (every one when None:
        `SessionSettings.differences`), and `split` ("split"). Given `data` but no split, the
        split a new session on `data` trains on is compared (`default_split`)."""
        found = []
        if data is not None and Path(data).resolve() != Path(self.source.data_dir).resolve():
            found.append(("data", str(data), self.source.data_dir))
        found += settings.differences(self.settings(), given)
        if split is None and data is not None:
            split = default_split(Path(data))[0]
        if split is not None and split != self.source.split:
            found.append(("split", split, self.source.split))
        return found

    @classmethod
    def from_dict(cls, data, path: Path) -> SessionState:
        """Parse and validate a session.json object.

        Raises:
            SessionError: naming `path`, the field and the value that is missing or wrong.
        """
        try:
            return cls.model_validate(data)
        except ValidationError as error:
            wrong = RequestError.of(error)
            where = f"{path}, field '{wrong.argument}'" if wrong.argument else str(path)
            got = f" (got {repr(wrong.value)[:120]})" if wrong.argument else ""  # not the whole file
            raise SessionError(
                f"{where}: {wrong.problem}{got}; the file was edited or damaged: "
                "restore it, or start a new session with `nerfaug train DATA --out NEW_RUN`"
            ) from None

    @classmethod
    def read(cls, run_dir: Path) -> SessionState:
        """The state in `run_dir/session.json`.

        Raises:
            SessionError: the file is missing, not JSON, or holds a missing or wrong value.
        """
        path = runfiles.shown(run_dir, SESSION_FILE)
        if not runfiles.exists(run_dir, SESSION_FILE):
            raise SessionError(
                f"{run_dir} is not a capture session: {SESSION_FILE} not found "
                f"(start one with `nerfaug train DATA --out {run_dir}`)"
            )
        try:
            data = json.loads(runfiles.read_text(run_dir, SESSION_FILE))  # PathRefused when it leads outside
        except json.JSONDecodeError as error:
            raise SessionError(f"{path}: invalid JSON at line {error.lineno}: {error.msg}") from None
        except (OSError, UnicodeDecodeError) as error:
            raise SessionError(f"{path}: cannot read: {error}") from None
        return cls.from_dict(data, path)


class SessionSummary(BaseModel):
    """What a session reports of itself (`CaptureSession.summary`): the service's state of it."""

    id: str = Field(description="the session's id: its run folder's name")
    step: int = Field(description="training steps done")
    views: int = Field(description="views in the dataset (all trained on once the model is loaded)")
    names: list[str] = Field(description="the views' file paths in the dataset")
    last_losses: list[dict] = Field(description="the last training steps' loss and PSNR")
    proposals: int
    additions: int
    hemisphere: dict = Field(description="centre, radius, up (world frame)")
    intrinsics: Intrinsics


def new_state(origin: SourceInfo, source, cameras, settings: SessionSettings, engine, config, background, hemisphere):
    """The `SessionState` of a new session on `source` (read from `origin`), whose cameras are
    `cameras`, its engine `config` (`engine`: an `Engine`, resolved once where the request entered,
    or "custom")."""
    return SessionState(
        source=origin,
        dataset=DatasetInfo.of(plainest_format(source, cameras)),
        engine=engine.record() if isinstance(engine, Engine) else engine,
        engine_config=config.to_dict(),
        seed=settings.seed,
        downscale=settings.downscale,
        background=tuple(float(c) for c in background),
        intrinsics=Intrinsics(
            width=cameras.width,
            height=cameras.height,
            fx=float(cameras.fx[0]),
            fy=float(cameras.fy[0]),
            cx=float(cameras.cx[0]),
            cy=float(cameras.cy[0]),
            camera_angle_x=float(cameras.camera_angle_x[0]),
        ),
        hemisphere=hemisphere,
        hemisphere_estimated={
            "centre": settings.centre is None,
            "radius": settings.radius is None,
            "up": settings.estimate_up,
        },
    )


def pole_settings(settings: SessionSettings, source: DatasetSplit, cameras: Cameras | None = None) -> SessionSettings:
    """`settings` with `estimate_up` decided for a session on `source`: as given, else on where the
    dataset's format records no up direction and no --up is given (`pole_is_estimated`).
    `cameras`: the split's, when loaded already."""
    if settings.estimate_up is not None:
        return settings
    cameras = source.load(lazy=True).cameras if cameras is None else cameras
    estimate = settings.up is None and pole_is_estimated(cameras.camera_to_world, source.format.z_up)
    return replace(settings, estimate_up=estimate)
