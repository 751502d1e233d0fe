"""What a capture session is asked, as typed schemas: each class (and each shared type) is the one
place of its fields, defaults, ranges and error text, used unchanged by the library, the CLI
(through tyro) and the service (as its request models).

Here: a new session's settings (`SessionSettings`), the camera of captured images (`Intrinsics`),
world-frame poses (`Pose`, `Poses`), a session's id (`SessionId`), the bounds the proposal
request and the view constraints (`nerfaug.capture.proposal_request`) build on, and those of
training steps, the save period, thread counts and uncertainty images' widths (`check_steps`,
`check_checkpoint_every`, `check_threads`, `check_image_widths`).

The classes tyro reads are `nerfaug.schema.Schema` dataclasses with one validator each,
`checked()` (pydantic, from their annotations): tyro builds them from the options without
checking, so that a refused value ends as one line naming its option (a check raised while tyro
builds them would be drawn as tyro's own box). A field's docstring is its help on the command line
and its description in the service's API page. `RequestError` names the first refused field, its
value and the problem.

Nothing here imports torch: `nerfaug train --help` reads these classes.
"""

from __future__ import annotations

import ast
import inspect
import math
import re
import textwrap
from dataclasses import dataclass, fields, make_dataclass
from typing import Annotated, Literal, get_args, get_origin, get_type_hints

import tyro
from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    PlainSerializer,
    PlainValidator,
    ValidationError,
    WithJsonSchema,
    model_validator,
)
from tyro.constructors import PrimitiveConstructorSpec

from nerfaug import camera_schema
from nerfaug.camera_schema import MAX_IMAGE_SIDE
from nerfaug.errors import DatasetError
from nerfaug.nerf.config import PRESETS
from nerfaug.nerf.engine import ENGINE_OPTION, Engine
from nerfaug.nerf.footprint import check_engine_fits
from nerfaug.registry import check_name
from nerfaug.schema import SCHEMA, RequestError, Schema, adapter, problem_text, validated


def replaced_by(default: str, metavar: str):
    """`--help` for an option whose default (None, or empty) means something: "(default: the
    hemisphere)" instead of "(default: None)"."""
    return tyro.conf.arg(metavar=metavar, help_behavior_hint=f"(default: {default})")


def given_form(schema: type) -> type:
    """`schema` as tyro reads it where an option given at its default value must be told from
    one not given: a frozen dataclass of the same fields, each None unless given (None cannot be
    written on the command line), with `schema`'s help, metavar and default in `--help`; its
    `given_names()` are the fields given, `filled()` the `schema` they give.

    Example:
        >>> Given = given_form(SessionSettings)
        >>> Given(seed=0)
        GivenSessionSettings(engine=None, seed=0, downscale=None, centre=None, radius=None, up=None, estimate_up=None)
        >>> Given(seed=0).given_names(), Given(seed=0).filled().seed
        ({'seed'}, 0)
    """
    hints, docs = get_type_hints(schema, include_extras=True), _field_docs(schema)
    form = []
    for f in fields(schema):
        kind, *meta = get_args(hints[f.name]) if get_origin(hints[f.name]) is Annotated else (hints[f.name],)
        shown = tyro.conf.arg(help=docs.get(f.name), help_behavior_hint=f"(default: {_shown(f.default)})")
        if get_origin(kind) is Literal:  # its names, without the None no one can write
            meta = [*meta, _one_of(tuple(get_args(kind)))]
        form.append((f.name, Annotated[kind | None, shown, *meta, tyro.conf.DisallowNone], None))

    def given_names(self) -> set[str]:
        """The fields given (not None), even at their default values."""
        return {f.name for f in fields(self) if getattr(self, f.name) is not None}

    def filled(self):
        """The `schema` this gives, the fields not given at their defaults."""
        return schema(**{name: getattr(self, name) for name in self.given_names()})

    methods = {"given_names": given_names, "filled": filled}
    return make_dataclass(f"Given{schema.__name__}", form, frozen=True, namespace=methods)


def _one_of(names: tuple[str, ...]) -> PrimitiveConstructorSpec:
    """How tyro reads an option that is one of `names` or not given (None): its choices shown and
    checked without "None", and a mistyped name answered with the closest ones (`registry.unknown`)."""

    def parse(words: list[str]) -> str:
        check_name("name", words[0], names)
        return words[0]

    return PrimitiveConstructorSpec(
        nargs=1,
        metavar="{" + ",".join(names) + "}",
        instance_from_str=parse,
        is_instance=lambda value: value is None or value in names,
        str_from_instance=lambda value: [str(value)],
    )


def _field_docs(schema: type) -> dict[str, str]:
    """The docstring under each field of the class `schema`, by field name."""
    body = ast.parse(textwrap.dedent(inspect.getsource(schema))).body[0].body
    return {
        line.target.id: " ".join(after.value.value.split())
        for line, after in zip(body, body[1:])
        if isinstance(line, ast.AnnAssign) and isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant)
    }


def _shown(value) -> str:
    """A default as tyro's `--help` shows it: (0.0, 0.0, 1.0) -> "0.0 0.0 1.0"."""
    return " ".join(map(str, value)) if isinstance(value, tuple) else str(value)


# ---- numbers and names ------------------------------------------------------------------------

# Seeds reach torch's generators (a signed 64-bit integer) and JSON clients, which read an integer
# exactly only up to 2^53 (JavaScript's numbers): a larger seed would come back rounded.
SEED_MAX = 2**53 - 1
Seed = Annotated[int, Field(ge=0, le=SEED_MAX)]
# A split's name: it becomes part of a file name (`transforms_{split}.json`), so no separators.
SPLIT_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")
Split = Annotated[
    str, Field(pattern=f"^{SPLIT_NAME.pattern}$", description="a split's name: letters, digits, '.', '_', '-'")
]
# The integer factor a session's images are shrunk by.
Downscale = Annotated[int, Field(ge=1, le=256)]
# A hemisphere radius, world units: beyond these a float32 engine frame loses the scene.
RADIUS_RANGE = (1e-6, 1e6)
Radius = Annotated[float, Field(ge=RADIUS_RANGE[0], le=RADIUS_RANGE[1])]
# Training steps one request may run: the same bounds on the command line and over HTTP. 0 is a
# step count too: `nerfaug add --steps 0` adds without training, `nerfaug train DATA --out RUN
# --steps 0` makes the session without training it, and a service's training job of 0 steps ends
# at once.
MAX_STEPS = 10_000_000
Steps = Annotated[int, Field(ge=0, le=MAX_STEPS)]
# A session's training saves this often (seconds of training; a killed process loses at most this
# much), and at the end (`CaptureSession.train_for`).
CHECKPOINT_EVERY_S = 60.0
CheckpointEvery = Annotated[float, Field(gt=0, description="seconds of training between saves")]
# CPU threads a command runs torch (or Blender's Cycles) on: more than any machine has would
# overflow the C int torch takes.
MAX_THREADS = 1024
Threads = Annotated[int, Field(ge=1, le=MAX_THREADS)]

# Pixels across of an uncertainty image (`nerfaug.capture.uncertainty_images`): a render holds
# width^2 rays and FisherRF's image three backward passes per pixel, so these bound the memory and
# time one request may take.
MAX_IMAGE_WIDTH = 1024
MAX_FISHER_WIDTH = 256
ImageWidth = Annotated[int, Field(ge=1, le=MAX_IMAGE_WIDTH)]
FisherWidth = Annotated[int, Field(ge=1, le=MAX_FISHER_WIDTH)]
# FisherRF's image unless told: three backward passes a pixel, so fewer pixels than the render.
FISHER_WIDTH = 16

# A session's id names its folder directly under the service root.
SESSION_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]{0,63}")


def _session_id(value: str) -> str:
    if not SESSION_ID.fullmatch(value):
        raise ValueError("must be 1-64 letters, digits, '_' or '-', starting with a letter or digit")
    return value


SessionId = Annotated[
    str,
    AfterValidator(_session_id),
    Field(description="1-64 letters, digits, '_' or '-'"),
]


def check_session_id(session_id) -> str:
    """`session_id` if it is a `SessionId`; RequestError ("session id 'a.b': ...") otherwise."""
    try:
        return adapter(SessionId).validate_python(session_id)
    except ValidationError as error:
        raise RequestError("session id", str(session_id)[:80], problem_text(error.errors()[0])) from None


def check_steps(steps: int) -> int:
    """`steps` (training steps to run) as an int; RequestError unless in 0..`MAX_STEPS`."""
    return validated(Steps, steps, "steps")


def check_checkpoint_every(seconds: float) -> float:
    """`seconds` (of training between saves) as a float; RequestError unless > 0."""
    return validated(CheckpointEvery, seconds, "checkpoint_every")


def check_threads(threads: int) -> int:
    """`threads` (CPU threads to run on) as an int; RequestError unless in 1..`MAX_THREADS`."""
    return validated(Threads, threads, "threads")


def check_image_widths(width: int | None, fisher_width: int) -> tuple[int | None, int]:
    """(`width`, `fisher_width`) of uncertainty images, pixels across (`width` None: the training
    resolution); RequestError unless in 1..`MAX_IMAGE_WIDTH` and 1..`MAX_FISHER_WIDTH`."""
    shown = None if width is None else validated(ImageWidth, width, "width")
    return shown, validated(FisherWidth, fisher_width, "fisher_width")


# ---- a sparse start -----------------------------------------------------------------------------

# A sparse start's layouts: the half of the object the initial views come from, turned a third of
# the way round from one layout to the next, as `nerfaug study --layouts 3` starts its trials.
START_LAYOUTS = 3


@dataclass(frozen=True, kw_only=True)
class SparseStart(Schema):
    """Start a session from a few of a dataset's views, the rest its candidate pool, as the
    paper's experiments start: `initial` views on one half of the object."""

    __pydantic_config__ = SCHEMA

    initial: Annotated[int, Field(ge=1, le=10_000)]
    """views to start from."""
    layout: Annotated[int, Field(ge=0, lt=START_LAYOUTS)] = 0
    """which half of the object they lie on: 0, 1 or 2, each turned a third of the way round."""


# ---- poses ------------------------------------------------------------------------------------


def _pose(value) -> list[list[float]]:
    """A rigid, finite 4x4 camera-to-world matrix (`nerfaug.camera_schema.check_pose`) as nested lists of floats."""
    value = value.tolist() if hasattr(value, "tolist") else value
    if any(isinstance(x, float) and not math.isfinite(x) for row in _rows(value) for x in row):
        raise ValueError("not finite (every entry of a pose must be a finite number)")
    try:
        camera_schema.check_pose(value, "pose", "pose")
    except ValueError as error:
        raise ValueError(getattr(error, "problem", "must be 4 rows of 4 numbers")) from None
    return [[float(x) for x in row] for row in value]


def _rows(value) -> list:
    """The rows of a would-be matrix (nothing when it has none)."""
    return [row for row in value if isinstance(row, list)] if isinstance(value, list) else []


def as_pose_list(value):
    """Poses as a list (a tensor or an array of them, or one 4x4 matrix, become one)."""
    if hasattr(value, "camera_to_world"):  # Cameras
        value = value.camera_to_world
    value = value.tolist() if hasattr(value, "tolist") else value
    one = isinstance(value, list) and len(value) == 4 and all(_rows(row) == [] for row in value)
    return [value] if one else value


_MATRIX = {"type": "array", "minItems": 4, "maxItems": 4, "items": {"type": "number"}}
Pose = Annotated[
    list[list[float]],
    PlainValidator(_pose),
    WithJsonSchema({"type": "array", "minItems": 4, "maxItems": 4, "items": _MATRIX}),
    Field(description="a world-frame OpenGL camera-to-world matrix: 4 rows of 4 numbers, rotation rigid"),
]
"""A world-frame camera-to-world pose (OpenGL: the camera looks down -z, +y up)."""
Poses = Annotated[list[Pose], BeforeValidator(as_pose_list), Field(min_length=1)]
"""World-frame poses, one or more; a tensor or array of shape (n, 4, 4) is taken as a list."""


def as_poses(value, field: str = "poses") -> list[list[list[float]]]:
    """`value` (nested lists, an (n, 4, 4) or (4, 4) tensor or array, or `Cameras`) as checked
    `Poses`; RequestError naming `field[i]` otherwise."""
    return validated(Poses, value, field)


# ---- the camera -------------------------------------------------------------------------------


class Intrinsics(BaseModel):
    """A camera in pixels, at full resolution: the session's (session.json) or that of uploaded
    images (fy, cx, cy default to fx, width/2, height/2)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, use_attribute_docstrings=True)

    width: int = Field(ge=1, le=MAX_IMAGE_SIDE)
    """image width, pixels"""
    height: int = Field(ge=1, le=MAX_IMAGE_SIDE)
    """image height, pixels"""
    fx: float = Field(gt=0)
    """focal length along x, pixels"""
    fy: float | None = Field(None, gt=0)
    """focal length along y, pixels (default: fx)"""
    cx: float | None = None
    """principal point x, pixels (default: width / 2)"""
    cy: float | None = None
    """principal point y, pixels (default: height / 2)"""
    camera_angle_x: float | None = Field(None, gt=camera_schema.MIN_FOV, lt=camera_schema.MAX_FOV)
    """horizontal field of view, radians (default: from width and fx)"""

    @model_validator(mode="after")
    def _defaults(self) -> Intrinsics:
        self.fy = self.fx if self.fy is None else self.fy
        self.cx = self.width / 2 if self.cx is None else self.cx
        self.cy = self.height / 2 if self.cy is None else self.cy
        if self.camera_angle_x is None:
            self.camera_angle_x = 2 * math.atan(self.width / (2 * self.fx))
        try:  # the camera schema every dataset reader holds cameras to
            camera_schema.check_pinhole(self.fx, self.fy, self.cx, self.cy, self.width, self.height, "intrinsics", str)
        except DatasetError as error:
            raise ValueError(error.problem) from None
        return self


# ---- a session's settings ---------------------------------------------------------------------

Vector = Annotated[tuple[float, float, float], Field(description="x, y, z, world frame")]


def _direction(value: tuple[float, float, float]) -> tuple[float, float, float]:
    if math.hypot(*value) < 1e-9:
        raise ValueError("must be a non-zero direction")
    return value


# A capture session's engine unless told: on a real capture (NeRF-synthetic mic at 100 px, all 100
# views, 1000 steps, seeds 0-9) `cpu` rendered 4 of 10 sessions as background only (its opaque start
# drives the colour network to saturated white) and `nerfacto-cpu` none, training faster
# (BENCHMARKS.md, "Empty NeRFs on a real capture").
DEFAULT_SESSION_ENGINE = "nerfacto-cpu"


def _engine(value) -> Engine:
    """The engine a request names (`Engine.read`: a preset, or a preset with settings changed),
    once one run of it fits this machine's memory; a refusal names the setting by its path."""
    try:
        return check_engine_fits(Engine.read(value))
    except ValueError as error:  # the refusal names the field and value before the reason
        named = value.get("preset") if isinstance(value, dict) else getattr(value, "preset", str(value))
        raise ValueError(str(error).removeprefix(f"engine {named!r}: ")) from None


# The JSON form of an engine: a preset's name, or an object naming the preset and the settings
# changed over it, by component as `NerfConfig` nests them.
ENGINE_JSON = {
    "anyOf": [
        {"type": "string", "enum": list(PRESETS)},
        {
            "type": "object",
            "properties": {
                "preset": {"type": "string", "enum": list(PRESETS)},
                **{group: {"type": "object"} for group in ("scene", "field", "sampler", "optimiser", "renderer")},
            },
            "required": ["preset"],
            "additionalProperties": False,
        },
    ],
    "examples": ["nerfacto-cpu", {"preset": "nerfacto-cpu", "field": {"hidden_dim": 48}}],
}

# A preset, with any of its settings changed (`--engine paper --engine.field.hidden-dim 32`; over
# HTTP {"preset": "paper", "field": {"hidden_dim": 32}}): read, checked and resolved once.
EngineName = Annotated[
    Engine,
    PlainValidator(_engine),
    PlainSerializer(Engine.record),
    WithJsonSchema(ENGINE_JSON),
    ENGINE_OPTION,
]


@dataclass(kw_only=True)
class SessionSettings(Schema):
    """What shapes a new session (`nerfaug train DATA --out RUN`); a session keeps its own."""

    __pydantic_config__ = SCHEMA

    # Its default shown in the service's schema as a request writes it.
    engine: Annotated[EngineName, Field(json_schema_extra={"default": DEFAULT_SESSION_ENGINE})] = Engine.of(
        DEFAULT_SESSION_ENGINE
    )
    """the NeRF engine: nerfacto-cpu (nerfacto shrunk), cpu (K-planes), paper (a GPU's), test; any of its
    settings changed with --engine.GROUP.SETTING (listed below)."""
    seed: Seed = 0
    """seeds the model, its training and every proposal (0 to 2^53-1, exact in any JSON client)."""
    downscale: Downscale = 1
    """train on images shrunk by this integer factor."""
    centre: Annotated[Vector | None, replaced_by("the point the cameras look at", "X Y Z")] = None
    """the hemisphere's centre, world space."""
    radius: Annotated[Radius | None, replaced_by("the cameras' mean distance to the centre", "FLOAT")] = None
    """the hemisphere's radius, world units (within 1000x of the cameras' distance to the centre)."""
    up: Annotated[
        Annotated[Vector, AfterValidator(_direction)] | None,
        replaced_by("+z; for LLFF and IDR/DTU captures the cameras' mean up axis", "FLOAT FLOAT FLOAT"),
    ] = None
    """the hemisphere's pole direction, world space."""
    estimate_up: Annotated[
        bool | None,
        tyro.conf.arg(help_behavior_hint="(default: on for LLFF and IDR/DTU captures, and nerfstudio ones not z-up)"),
    ] = None
    """take the pole from the cameras' mean up axis (on) or from --up, else +z (off); formats that record no up
    direction have it on unless --up is given."""

    def differences(self, ours: SessionSettings, given=None) -> list[tuple[str, str, str]]:
        """The settings named in `given` (field names; every one when None) that differ from a
        session's `ours`, each as (field, this value, the session's), in words ("0 0 1",
        "estimated", "on").

        None for the centre or the radius means estimated; an estimated pole is compared as
        `estimate_up` when that is given too (one difference, not two)."""
        given = {f.name for f in fields(SessionSettings)} if given is None else given
        found = []
        for f in fields(SessionSettings):
            if f.name not in given or (f.name == "up" and self._up_skipped(ours, given)):
                continue
            mine, theirs = getattr(self, f.name), getattr(ours, f.name)
            if f.name == "up" and (mine is None or (not ours.estimate_up and _close(_unit(mine), _unit(theirs)))):
                continue  # no pole asked for (None: the format's), or the session's own
            if f.name == "estimate_up" and mine is None:
                continue  # the default follows the dataset's format, which the session took already
            if f.name != "up" and _close(mine, theirs):
                continue
            asked = "not given, so estimated" if mine is None else _words(mine, f.name, self)
            found.append((f.name, asked, _words(theirs, f.name, ours)))
        return found

    def _up_skipped(self, ours: SessionSettings, given) -> bool:
        return self.estimate_up or (ours.estimate_up and "estimate_up" in given)


def _words(value, name: str, settings: SessionSettings) -> str:
    """A setting as the command line writes it; a centre, radius or pole the session estimated
    says so."""
    if value is None or (name == "up" and settings.estimate_up):
        return "estimated"
    if isinstance(value, bool):
        return "on" if value else "off"
    return words(value)


def words(value) -> str:
    """A value as the command line writes it: (60.0, 10.0) -> "60 10", 1e-300 -> "1e-300"."""
    if isinstance(value, (tuple, list)):
        return " ".join(words(x) for x in value)
    return f"{value:g}" if isinstance(value, float) else str(value)


def _close(a, b) -> bool:
    """Two settings equal (numbers to within float noise)."""
    if a is None or b is None or isinstance(a, (str, bool, Engine)) or isinstance(b, (str, bool, Engine)):
        return a == b
    a, b = (tuple(x) if isinstance(x, (tuple, list)) else (x,) for x in (a, b))
    return len(a) == len(b) and all(math.isclose(float(x), float(y), rel_tol=1e-6, abs_tol=1e-9) for x, y in zip(a, b))


def _unit(v) -> tuple[float, ...]:
    norm = math.sqrt(sum(float(x) ** 2 for x in v)) or 1.0
    return tuple(float(x) / norm for x in v)
