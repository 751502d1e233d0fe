"""The service's requests and answers as pydantic models (they make the OpenAPI page at /docs).

Poses are world-frame OpenGL camera-to-world 4x4 matrices (rows of 4 numbers), as in the
Blender and nerfstudio formats; angles of constraints are in degrees (`ViewConstraints`).
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from nerfaug.capture.requests import RADIUS_RANGE, SEED_MAX, SPLIT_NAME
from nerfaug.nerf.config import EnginePreset
from nerfaug.service.hub import SESSION_ID
from nerfaug.service.limits import (
    MAX_CANDIDATES,
    MAX_CAPTURES_PER_REQUEST,
    MAX_IMAGE_PIXELS,
    MAX_KEEP_OUT,
    MAX_REACHABLE_POSES,
    MAX_VIEWS,
    SELECTION_BOUNDS,
)

Pose = list[list[float]]
SessionId = Field(pattern=f"^{SESSION_ID.pattern}$", description="1-64 letters, digits, '_' or '-'")
Seed = Annotated[int, Field(ge=0, le=SEED_MAX)]
Split = Annotated[
    str, Field(pattern=f"^{SPLIT_NAME.pattern}$", description="a split name: letters, digits, '.', '_', '-'")
]
Elevation = Annotated[float, Field(ge=-90, le=90)]
Azimuth = Annotated[float, Field(ge=-720, le=720)]
Distance = Annotated[float, Field(ge=0, le=RADIUS_RANGE[1] * 1000)]


class Strict(BaseModel):
    """Unknown fields and non-finite numbers are refused, naming the field."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class SessionSettings(Strict):
    """A new session's settings (as `nerfaug train DATA --out RUN`)."""

    id: str = SessionId
    preset: EnginePreset = Field("cpu", description="NeRF engine preset")
    seed: Seed = Field(0, description="seeds the model, its training and every proposal (0 to 2^63-1)")
    downscale: int = Field(1, ge=1, le=256, description="train on images shrunk by this integer factor")
    centre: tuple[float, float, float] | None = Field(None, description="hemisphere centre; default: estimated")
    radius: float | None = Field(
        None,
        ge=RADIUS_RANGE[0],
        le=RADIUS_RANGE[1],
        description="hemisphere radius, world units, within 1000x of the cameras' distance; default: estimated",
    )
    up: tuple[float, float, float] = Field((0.0, 0.0, 1.0), description="the hemisphere's pole, world frame")


class CreateFromDataset(SessionSettings):
    """A session on a dataset folder inside the service root."""

    dataset: str = Field(
        max_length=1024, description="a Blender or nerfstudio dataset folder, relative to the service root"
    )
    split: Split | None = Field(None, description="the Blender split of the captured views (default: train)")


class Intrinsics(Strict):
    """The camera of uploaded images, in pixels (fy, cx, cy default to fx, width/2, height/2)."""

    width: int = Field(ge=1, le=16384)
    height: int = Field(ge=1, le=16384)
    fx: float = Field(gt=0)
    fy: float | None = Field(None, gt=0)
    cx: float | None = None
    cy: float | None = None

    @model_validator(mode="after")
    def _pixels(self):
        if self.width * self.height > MAX_IMAGE_PIXELS:
            raise ValueError(f"{self.width}x{self.height} pixels is over the limit of {MAX_IMAGE_PIXELS} pixels")
        return self


class CreateFromUploads(SessionSettings):
    """The `settings` form field of a session made from uploaded images (one pose per image)."""

    intrinsics: Intrinsics
    poses: list = Field(
        max_length=MAX_CAPTURES_PER_REQUEST,
        description=f"one 4x4 camera-to-world pose per uploaded image, in upload order (at most "
        f"{MAX_CAPTURES_PER_REQUEST})",
    )


class TrainRequest(Strict):
    steps: int = Field(ge=1, le=10_000_000, description="training steps to run in the background")


class Constraints(Strict):
    """Where proposed views may lie (degrees, world units); see `nerfaug propose --help`."""

    elevation: tuple[Elevation, Elevation] | None = Field(
        None, description="(low, high) degrees above the equator, in [-90, 90]"
    )
    azimuth: tuple[Azimuth, Azimuth] | None = Field(
        None, description="(low, high) degrees about up, in [-720, 720]; may wrap"
    )
    radius: tuple[Distance, Distance] | None = Field(None, description="(low, high) distance from the centre")
    keep_out: list[tuple[float, float, float, Annotated[float, Field(gt=0, lt=180)]]] = Field(
        default_factory=list,
        max_length=MAX_KEEP_OUT,
        description=f"cones to avoid: (x, y, z, half_angle_degrees in (0, 180)), direction from the centre; at "
        f"most {MAX_KEEP_OUT}",
    )


class ProposeRequest(Strict):
    n: int = Field(6, ge=1, le=MAX_VIEWS, description="views to propose")
    method: str = Field("ours", max_length=100, description="a selection method (`nerfaug methods`)")
    n_candidates: int = Field(500, ge=1, le=MAX_CANDIDATES, description="hemisphere candidates to score")
    seed: Seed | None = Field(None, description="0 to 2^63-1; default: from the session seed and proposal number")
    selection: dict = Field(
        default_factory=dict,
        description="SelectionConfig fields (`--selection.*`), each of its type; the ones that set the work are "
        "bounded: " + ", ".join(f"{k} <= {v}" for k, v in SELECTION_BOUNDS.items()),
    )
    constraints: Constraints | None = None
    candidates: list | None = Field(
        None,
        max_length=MAX_REACHABLE_POSES,
        description=f"reachable 4x4 poses to choose from instead of the hemisphere (at most {MAX_REACHABLE_POSES})",
    )

    min_separation: float = Field(
        0.0, ge=0, lt=180, description="degrees between any two proposed views, seen from the centre (0: off)"
    )

    @field_validator("selection")
    @classmethod
    def _bounded(cls, value: dict) -> dict:
        for name, most in SELECTION_BOUNDS.items():
            given = value.get(name)
            if isinstance(given, (int, float)) and not isinstance(given, bool) and given > most:
                raise ValueError(f"{name} {given}: at most {most} in one request")
        return value


class UncertaintyRequest(Strict):
    pose: Pose = Field(description="the view's 4x4 camera-to-world pose")
    width: int | None = Field(None, ge=1, le=1024, description="pixels across; default: the training resolution")
    fisher: bool = Field(True, description="also FisherRF's per-pixel score (slower)")
    fisher_width: int = Field(16, ge=1, le=256, description="pixels across of the FisherRF image")
    format: Literal["png", "npz"] = Field("png", description="png: the figure; npz: the arrays")


class EvaluateRequest(Strict):
    """Held-out views to score the session's NeRF on (as `nerfaug eval RUN --data DATA`)."""

    dataset: str = Field(
        max_length=1024, description="a dataset folder of the same scene and world frame, relative to the service root"
    )
    split: Split = Field("test", description="the split to score")
    max_views: int | None = Field(None, ge=1, description="score only the split's first views (default: all)")
    lpips: bool = Field(True, description="also LPIPS (when its weights are installed and images are large enough)")


class Evaluation(BaseModel):
    step: int
    dataset: str
    split: str
    views: int
    psnr: float | None
    ssim: float | None
    lpips: float | None
    lpips_status: str
    per_view: list[dict]


class Job(BaseModel):
    target: int
    start: int
    step: int
    state: Literal["running", "done", "failed"]
    error: str | None
    started: float
    finished: float | None
    progress: float
    resumed_from: int | None = Field(
        None, description="a job a restarted service resumed: the step of the session's last save it went on from"
    )
    redone: int = Field(0, description="steps trained after that save before the service stopped, trained again")


class SessionState(BaseModel):
    id: str
    step: int
    views: int
    names: list[str]
    last_losses: list[dict]
    proposals: int
    additions: int
    hemisphere: dict
    intrinsics: dict
    running: bool
    job: Job | None


class Added(BaseModel):
    names: list[str]
    views: int
    step: int
    warnings: list[str] = Field(default_factory=list, description="what `nerfaug add` would warn about (one line each)")


class Health(BaseModel):
    status: Literal["ok"]
    version: str
    sessions: list[str]
