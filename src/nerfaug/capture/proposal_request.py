"""What a proposal is asked, as typed schemas: which views, by which method, from which candidates
(`ProposalRequest`), and where they may lie (`ViewConstraints`), each with its bounds; checked here
for the library, the CLI and the service alike (`nerfaug.capture.requests` has the shared types).

Angles of constraints are in degrees, as a user states a workspace (`nerfaug.capture.constraints`
applies them to candidate poses). Nothing here imports torch: `nerfaug propose --help` reads it.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Annotated

import tyro
from pydantic import AfterValidator, BeforeValidator, Field, WrapValidator
from tyro.constructors import PrimitiveConstructorSpec

from nerfaug.capture.requests import (
    RADIUS_RANGE,
    SCHEMA,
    Pose,
    Schema,
    Seed,
    as_pose_list,
    replaced_by,
    validated,
)
from nerfaug.registry import check_name
from nerfaug.selection.config import SelectionConfig

# The ranges a constraint may state: elevation in degrees about the equator, azimuth in degrees
# (an arc may wrap, up to two turns either way), distances in world units.
Elevation = Annotated[float, Field(ge=-90, le=90)]
Azimuth = Annotated[float, Field(ge=-720, le=720)]
Distance = Annotated[float, Field(ge=0, le=RADIUS_RANGE[1] * 1000)]
HalfAngle = Annotated[float, Field(gt=0, lt=180)]
# Keep-out cones one request may state.
MAX_KEEP_OUT = 64


def _ordered(pair: tuple[float, float]) -> tuple[float, float]:
    if pair[0] > pair[1]:
        raise ValueError("low must be <= high")
    return pair


def _pointing(cone: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
    if math.hypot(*cone[:3]) < 1e-12:
        raise ValueError("the direction (x, y, z) must not be zero")
    return cone


Cone = Annotated[tuple[float, float, float, HalfAngle], AfterValidator(_pointing)]


@dataclass(kw_only=True)
class ViewConstraints(Schema):
    """Where proposed views may lie (degrees, world units): ranges about the session's hemisphere,
    applied to the hemisphere's candidates or to reachable poses, and keep-out cones."""

    __pydantic_config__ = SCHEMA

    elevation: Annotated[
        Annotated[tuple[Elevation, Elevation], AfterValidator(_ordered)] | None, replaced_by("any", "LOW HIGH")
    ] = None
    """(low, high) degrees above the hemisphere's equator, in [-90, 90]."""
    azimuth: Annotated[
        Annotated[tuple[Azimuth, Azimuth], AfterValidator(_ordered)] | None, replaced_by("any", "LOW HIGH")
    ] = None
    """(low, high) degrees about the hemisphere's up, counter-clockwise, in [-720, 720]; may wrap: 315 405."""
    radius: Annotated[
        Annotated[tuple[Distance, Distance], AfterValidator(_ordered)] | None, replaced_by("any", "LOW HIGH")
    ] = None
    """(low, high) distance from the hemisphere's centre, world units (for reachable poses)."""
    keep_out: Annotated[
        tuple[Cone, ...],
        Field(max_length=MAX_KEEP_OUT),
        replaced_by("no cone", "X Y Z HALF_ANGLE [X Y Z HALF_ANGLE ...]"),
    ] = ()
    """cones to stay out of: a world-frame direction from the centre and a half-angle (0, 180) degrees each."""

    @property
    def empty(self) -> bool:
        """True when nothing is constrained."""
        return self.elevation is None and self.azimuth is None and self.radius is None and not self.keep_out

    def to_dict(self) -> dict:
        """JSON-ready: lists for the ranges and cones (recorded with a proposal)."""
        ranges = {k: None if v is None else list(v) for k, v in asdict(self).items() if k != "keep_out"}
        return {**ranges, "keep_out": [list(c) for c in self.keep_out]}

    @classmethod
    def from_dict(cls, data: dict | None) -> ViewConstraints:
        """The inverse of `to_dict`, checked (RequestError naming the field otherwise)."""
        return validated(cls, data or {})


# Two proposed views closer than this (degrees about the hemisphere's centre) see nearly the same
# image (a NeRF-synthetic camera's field of view is about 40 degrees) and parallax: the second
# is nearly wasted. Sampling methods draw such pairs freely (two views 5 degrees apart on the lego);
# the paper's experiments keep no separation and never read this default (`experiment` selects
# without it). Six views 15 degrees apart fit many times over on the hemisphere.
DEFAULT_MIN_SEPARATION = 15.0

# What one proposal may ask: views, hemisphere candidates to score, reachable poses to choose from.
MAX_VIEWS = 1000
MAX_CANDIDATES = 20_000
MAX_REACHABLE_POSES = 10_000


def _known_method(method: str) -> str:
    from nerfaug.selection.methods import METHODS  # torch: here, so that `nerfaug propose --help` loads none

    check_name("selection method", method, METHODS)
    return method


def _reachable(value, handler):
    """A transforms JSON of poses (a `Path`: from Python or the command line, never from JSON),
    or the poses themselves, checked."""
    return value if isinstance(value, Path) else handler(value)


# `--candidates PATH` on the command line: a transforms JSON of reachable poses.
_FILE = PrimitiveConstructorSpec(
    nargs=1,
    metavar="PATH",
    instance_from_str=lambda words: Path(words[0]),
    is_instance=lambda value: value is None or isinstance(value, (Path, list)),
    str_from_instance=lambda value: ["None" if value is None else str(value)],
)
Reachable = Annotated[
    list[Pose],
    BeforeValidator(as_pose_list),
    Field(min_length=1, max_length=MAX_REACHABLE_POSES),
    WrapValidator(_reachable),
]


@dataclass(kw_only=True)
class ProposalRequest(Schema):
    """What to propose: which views, by which method, from which candidates, where they may lie.

    `checked()` is the one place its values are checked: the library, the CLI (before it opens the
    session) and the service (as its request model) call it.
    """

    __pydantic_config__ = SCHEMA

    n: Annotated[int, Field(ge=1, le=MAX_VIEWS)] = 6
    """views to propose."""
    method: Annotated[str, Field(max_length=100), AfterValidator(_known_method)] = "ours"
    """the selection method (`nerfaug methods` lists them); "ours" is the paper's."""
    candidates: Annotated[Reachable | None, _FILE, replaced_by("the hemisphere", "PATH")] = None
    """reachable poses (a robot's) to choose from instead of the hemisphere: a transforms JSON, or 4x4 poses."""
    n_candidates: Annotated[int, Field(ge=1, le=MAX_CANDIDATES)] = 500
    """hemisphere candidates to score."""
    seed: Annotated[Seed | None, replaced_by("the session's, per proposal", "INT")] = None
    """seed this proposal (0 to 2^53-1); by default the session's seed and proposal number seed it."""
    selection: SelectionConfig = field(default_factory=SelectionConfig)
    """options of the selection method (recorded with the proposal); a method's own settings apply over them."""
    constraints: Annotated[ViewConstraints, tyro.conf.arg(name="")] = field(default_factory=ViewConstraints)
    """where views may lie, applied to the hemisphere's candidates or to the reachable poses."""
    min_separation: Annotated[float, Field(ge=0, lt=180)] = DEFAULT_MIN_SEPARATION
    """keep every two proposed views this many degrees apart, seen from the hemisphere's centre (0: off)."""
    allow_empty: bool = False
    """propose even from a NeRF whose renders of its training views are background only (refused otherwise)."""
