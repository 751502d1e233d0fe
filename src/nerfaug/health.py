"""Whether a trained NeRF learned its scene: a NeRF whose renders of its own training views are
background only (all-transparent), or no closer to them than a blank image, has nothing to say
about which views to capture next: a proposal from it is refused (`EmptyModel`) unless asked for
all the same, and then said to be so (a warning), never silently sent to a robot.

The check renders the training views small (`HEALTH_WIDTH` pixels across, at most
`HEALTH_VIEWS` of them, spread over the set) and compares with the images shrunk alike: the mean
opacity over the object's pixels (those that differ from the background), and the PSNR of the
renders against that of a blank image of the background colour.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch

from nerfaug.errors import NerfaugError

HEALTH_WIDTH = 32
HEALTH_VIEWS = 12
# A pixel is the object's where some channel differs from the background by more than this.
OBJECT_DIFFERENCE = 0.05
# Empty: the object's pixels are rendered at most this opaque on average...
MIN_OBJECT_OPACITY = 0.05
# ...or the renders are within this many dB of a blank image's PSNR.
MIN_GAIN_OVER_BLANK_DB = 0.5


class EmptyModelWarning(UserWarning):
    """A proposal made (as asked: `allow_empty`) from a NeRF that renders its training views as
    background only."""


class EmptyModel(NerfaugError):
    """A proposal refused: the NeRF renders its training views as background only (`Health`).
    Not bad input (the request is fine; the model is not): exit code 1, HTTP 409."""

    exit_code = 1


@dataclass(frozen=True)
class Health:
    """What the check measured.

    Attributes:
        object_fraction: the share of the (shrunk) training pixels that show the object.
        object_opacity: the mean rendered opacity over those pixels (nan where there are none).
        psnr: the renders' PSNR against the shrunk training images, in dB.
        blank_psnr: a blank image of the background colour's PSNR against them, in dB.
        views: how many training views were rendered.
    """

    object_fraction: float
    object_opacity: float
    psnr: float
    blank_psnr: float
    views: int

    @property
    def empty(self) -> bool:
        """Whether the NeRF learned nothing: the object's pixels rendered (nearly) transparent,
        or the renders no better than a blank image. Images without an object are never empty."""
        if self.object_fraction <= 0.0:
            return False
        transparent = self.object_opacity < MIN_OBJECT_OPACITY
        return transparent or self.psnr < self.blank_psnr + MIN_GAIN_OVER_BLANK_DB

    def line(self) -> str:
        """The finding in one line, with what to do when the NeRF is empty."""
        measured = (
            f"opacity {self.object_opacity:.3f} over the object's pixels, PSNR {self.psnr:.2f} dB against "
            f"{self.blank_psnr:.2f} dB for a blank image, on {self.views} training views"
        )
        if not self.empty:
            return f"the NeRF learned its views ({measured})"
        return (
            f"the NeRF renders its training views as background only ({measured}): train longer, with "
            "another --seed, or with another --engine (nerfacto-cpu) before asking it which views to capture"
        )

    def to_dict(self) -> dict:
        return {**asdict(self), "empty": self.empty}


def _psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    return -10.0 * math.log10(max(float((a - b).square().mean()), 1e-10))


def model_health(model, views, background=(1.0, 1.0, 1.0)) -> Health:
    """Render up to `HEALTH_VIEWS` of `views` (a NeRF's training views) `HEALTH_WIDTH` pixels
    across with `model` (a `NerfModel`) and measure what it learned (`Health`).

    Args:
        views: `Views` with images (n, H, W, 3) in [0, 1], composited over `background`.
        background: the colour the images were composited over (RGB in [0, 1]).
    """
    from nerfaug.data.views import spread_over_frames

    device = model.background.device
    chosen = spread_over_frames(min(HEALTH_VIEWS, len(views)), len(views))
    cameras = views.cameras
    width = min(HEALTH_WIDTH, cameras.width)
    height = max(1, round(width * cameras.height / cameras.width))
    small = cameras.resized(width, height)
    colour = torch.as_tensor(background, dtype=torch.float32).reshape(1, 1, 3)
    renders, opacities, targets = [], [], []
    for index in chosen:
        image = views.image(index).float().cpu()
        # Area averaging: each small pixel is the mean of the image pixels it covers.
        target = torch.nn.functional.interpolate(image.permute(2, 0, 1)[None], (height, width), mode="area")
        targets.append(target[0].permute(1, 2, 0))
        out = model.render_image(small.to(device), index)
        renders.append(out["rgb"].clamp(0, 1).cpu())
        opacities.append(out["accumulation"].cpu())
    render, opacity, target = torch.stack(renders), torch.stack(opacities), torch.stack(targets)
    objects = (target - colour).abs().amax(dim=-1) > OBJECT_DIFFERENCE
    fraction = float(objects.float().mean())
    object_opacity = float(opacity[objects].mean()) if bool(objects.any()) else math.nan
    blank = colour.expand_as(target)
    return Health(fraction, object_opacity, _psnr(render, target), _psnr(blank, target), len(chosen))
