"""The service's requests and answers (they make the OpenAPI page at /docs) beyond the capture
core's schemas (`nerfaug.capture.requests`, `ProposalRequest`, `ViewConstraints`; a session's
state and training job, `nerfaug.capture.pool`'s `SessionStatus` and `Job`): the core's with what
only the service adds, a session's id and datasets named relative to its root.

Poses are world-frame OpenGL camera-to-world 4x4 matrices (rows of 4 numbers), as in the
Blender and nerfstudio formats; angles of constraints are in degrees.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

from nerfaug.capture.pool import SessionStatus
from nerfaug.capture.requests import (
    FISHER_WIDTH,
    SCHEMA,
    FisherWidth,
    ImageWidth,
    Intrinsics,
    Pose,
    Poses,
    SessionId,
    SessionSettings,
    Split,
    Steps,
)
from nerfaug.service.limits import MAX_CAPTURES_PER_REQUEST

Dataset = Annotated[str, Field(max_length=1024, description="a dataset folder, relative to the service root")]
# The service's own request models, as the core's schemas (`SCHEMA`): a field they do not have is
# refused (422 naming it), never ignored.
REQUEST = ConfigDict(extra="forbid")


@dataclass(kw_only=True)
class FromDataset(SessionSettings):
    """A session on a dataset folder inside the service root (as `nerfaug train DATA --out RUN`)."""

    __pydantic_config__ = SCHEMA

    id: SessionId
    """the session's id: its folder under the service root."""
    dataset: Dataset
    """a Blender or nerfstudio dataset folder, relative to the service root."""
    split: Split | None = None
    """the split of the captured views (default: "initial" for a dataset nerfaug rendered, else "train")."""


@dataclass(kw_only=True)
class FromUploads(SessionSettings):
    """The `settings` form field of a session made from uploaded images (one pose per image)."""

    __pydantic_config__ = SCHEMA

    id: SessionId
    """the session's id: its folder under the service root."""
    intrinsics: Intrinsics
    """the camera of the images."""
    poses: Annotated[Poses, Field(max_length=MAX_CAPTURES_PER_REQUEST)]
    """one pose per uploaded image, in upload order."""


class TrainRequest(BaseModel):
    model_config = REQUEST

    steps: Steps = Field(description="training steps to run in the background (as `nerfaug add --steps`; 0: none)")


class UncertaintyRequest(BaseModel):
    model_config = REQUEST

    pose: Pose = Field(description="the view's 4x4 camera-to-world pose")
    width: ImageWidth | None = Field(None, description="pixels across; default: the training resolution")
    fisher: bool = Field(True, description="also FisherRF's per-pixel score (slower)")
    fisher_width: FisherWidth = Field(FISHER_WIDTH, description="pixels across of the FisherRF image")
    format: Literal["png", "npz"] = Field("png", description="png: the figure; npz: the arrays")


class EvaluateRequest(BaseModel):
    """Held-out views to score the session's NeRF on (as `nerfaug eval RUN --data DATA`)."""

    model_config = REQUEST

    dataset: Dataset
    split: Split | None = Field(
        None,
        description="the split to score (default: the views the session's sparse start kept apart for testing, "
        "where it kept some; else test)",
    )
    max_views: int | None = Field(
        None,
        ge=1,
        description="score only this many of the split's views, spread evenly over its frames (default: all)",
    )
    lpips: bool = Field(True, description="also LPIPS (when its weights are installed and images are large enough)")


class Created(SessionStatus):
    """A new session's state, and what its creation warned about."""

    warnings: list[str] = Field(
        default_factory=list,
        description="what `nerfaug train` would warn about when it creates the session: the same view twice, a "
        "hemisphere pole far from the cameras' up (one line each)",
    )


class Evaluation(BaseModel):
    step: int
    dataset: str
    split: str
    views: int
    psnr: float | None
    ssim: float | None
    lpips: float | None
    lpips_status: str
    trained_on: int = Field(
        0, description="views whose pose the session trains on: they score the fit, not held-out views (see per_view)"
    )
    scored: str = Field(
        "", description="which views were scored: a split, or the views a sparse start kept apart (named in per_view)"
    )
    note: str | None = Field(None, description="why views the session trains on may be among them (one line)")
    per_view: list[dict]


class Added(BaseModel):
    names: list[str]
    views: int
    step: int
    warnings: list[str] = Field(default_factory=list, description="what `nerfaug add` would warn about (one line each)")


class Health(BaseModel):
    status: Literal["ok"]
    version: str
    sessions: list[str]
