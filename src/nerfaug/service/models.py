"""The service's requests and answers as pydantic models (they make the OpenAPI page at /docs).

Poses are world-frame OpenGL camera-to-world 4x4 matrices (rows of 4 numbers), as in the
Blender and nerfstudio formats; angles of constraints are in degrees (`ViewConstraints`).
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from nerfaug.nerf.config import EnginePreset
from nerfaug.service.hub import SESSION_ID

Pose = list[list[float]]
SessionId = Field(pattern=f"^{SESSION_ID.pattern}$", description="1-64 letters, digits, '_' or '-'")


class Strict(BaseModel):
    """Unknown fields and non-finite numbers are refused, naming the field."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class SessionSettings(Strict):
    """A new session's settings (as `nerfaug train DATA --out RUN`)."""

    id: str = SessionId
    preset: EnginePreset = Field("cpu", description="NeRF engine preset")
    seed: int = Field(0, ge=0, description="seeds the model, its training and every proposal")
    downscale: int = Field(1, ge=1, description="train on images shrunk by this integer factor")
    centre: tuple[float, float, float] | None = Field(None, description="hemisphere centre; default: estimated")
    radius: float | None = Field(None, gt=0, description="hemisphere radius; default: estimated")
    up: tuple[float, float, float] = Field((0.0, 0.0, 1.0), description="the hemisphere's pole, world frame")


class CreateFromDataset(SessionSettings):
    """A session on a dataset folder inside the service root."""

    dataset: str = Field(description="a Blender or nerfstudio dataset folder, relative to the service root")
    split: str | None = Field(None, description="the Blender split of the captured views (default: train)")


class Intrinsics(Strict):
    """The camera of uploaded images, in pixels (fy, cx, cy default to fx, width/2, height/2)."""

    width: int = Field(ge=1, le=16384)
    height: int = Field(ge=1, le=16384)
    fx: float = Field(gt=0)
    fy: float | None = Field(None, gt=0)
    cx: float | None = None
    cy: float | None = None


class CreateFromUploads(SessionSettings):
    """The `settings` form field of a session made from uploaded images (one pose per image)."""

    intrinsics: Intrinsics
    poses: list = Field(description="one 4x4 camera-to-world pose per uploaded image, in upload order")


class TrainRequest(Strict):
    steps: int = Field(ge=1, le=10_000_000, description="training steps to run in the background")


class Constraints(Strict):
    """Where proposed views may lie (degrees, world units); see `nerfaug propose --help`."""

    elevation: tuple[float, float] | None = Field(None, description="(low, high) degrees above the equator")
    azimuth: tuple[float, float] | None = Field(None, description="(low, high) degrees about up; may wrap")
    radius: tuple[float, float] | None = Field(None, description="(low, high) distance from the centre")
    keep_out: list[tuple[float, float, float, float]] = Field(
        default_factory=list, description="cones to avoid: (x, y, z, half_angle_degrees), direction from the centre"
    )


class ProposeRequest(Strict):
    n: int = Field(6, ge=1, le=1000, description="views to propose")
    method: str = Field("ours", description="a selection method (`nerfaug methods`)")
    n_candidates: int = Field(500, ge=1, le=100_000, description="hemisphere candidates to score")
    seed: int | None = Field(None, ge=0, description="default: from the session seed and proposal number")
    selection: dict = Field(default_factory=dict, description="SelectionConfig fields (`--selection.*`)")
    constraints: Constraints | None = None
    candidates: list | None = Field(None, description="reachable 4x4 poses to choose from instead of the hemisphere")
    min_separation: float = Field(
        0.0, ge=0, lt=180, description="degrees between any two proposed views, seen from the centre (0: off)"
    )


class UncertaintyRequest(Strict):
    pose: Pose = Field(description="the view's 4x4 camera-to-world pose")
    width: int | None = Field(None, ge=1, le=1024, description="pixels across; default: the training resolution")
    fisher: bool = Field(True, description="also FisherRF's per-pixel score (slower)")
    fisher_width: int = Field(16, ge=1, le=256, description="pixels across of the FisherRF image")
    format: Literal["png", "npz"] = Field("png", description="png: the figure; npz: the arrays")


class EvaluateRequest(Strict):
    """Held-out views to score the session's NeRF on (as `nerfaug eval RUN --data DATA`)."""

    dataset: str = Field(description="a dataset folder of the same scene and world frame, relative to the service root")
    split: str = Field("test", description="the split to score")
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


class Health(BaseModel):
    status: Literal["ok"]
    version: str
    sessions: list[str]
