"""Whether a trained NeRF learned its scene: a NeRF whose renders of its own training views are
background only (all-transparent), or no closer to them than an image without structure, has
nothing to say about which views to capture next: a proposal from it is refused (`EmptyModel`)
unless asked for all the same, and then said to be so (a warning), never silently sent to a robot.

The check renders the training views small (`HEALTH_WIDTH` pixels across, at most
`HEALTH_VIEWS` of them, spread over the set) and compares with the images shrunk alike, against
two baselines of the scene itself rather than a fixed margin:

- the blank image: the background colour everywhere (what an empty NeRF renders);
- the mean-colour image: each training image's own mean colour everywhere. A constant is closest
  to an image (least squared error) at its mean, so no render without structure (one flat
  colour, even one that changes with the view) scores above it; it also scores at least the
  blank image, so it is the stricter of the two. The per-image mean rather than the mean over
  the set: a NeRF's colour may depend on the view direction, and a flat colour per view must
  not pass either.

The NeRF is empty when the object's pixels are rendered (nearly) transparent, or when its
renders do not explain a fifth of a baseline's squared error (`MIN_GAIN_DB`); `Health.reason` names the
test that failed.

Poses the NeRF did not train on (e.g. a proposal's candidates) can be rendered beside them: how
much of those renders shows anything is reported, never a reason to refuse (a sparse start is
expected to generalise poorly).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch

from nerfaug.errors import NerfaugError

HEALTH_WIDTH = 32
HEALTH_VIEWS = 12
# Untrained poses rendered beside them: a few suffice to see whether the NeRF shows anything off
# its training views; each costs one small render.
UNTRAINED_VIEWS = 4
# A pixel is the object's where some channel differs from the background by more than this.
OBJECT_DIFFERENCE = 0.05
# Empty: the object's pixels are rendered at most this opaque on average...
MIN_OBJECT_OPACITY = 0.05
# ...or the renders leave more than 80 % of a baseline's squared error: they must explain at least
# a fifth of what the mean colour leaves unexplained (R^2 >= 0.2), -10 log10(0.8) = 0.97 dB over
# it. Why so: no render without structure can score above 0 dB over the mean-colour image (the
# least-squares constant), so anything above it is structure; the cow's 8 recorded empty runs
# score -1.0 to -0.9 dB over it, and the living run that fits worst (the cow, nerfacto-cpu,
# all views, seed 4: training PSNR 19.9 dB) +3.4 dB (BENCHMARKS.md, "The health check against
# per-scene baselines"). A fifth sits in that gap with room on both sides, and, as a ratio of the
# scene's own error, means the same on a white-background render (blank image at 14 dB) as on a
# photo set (5.5 dB).
MIN_GAIN_DB = -10.0 * math.log10(0.8)
# An untrained pose renders empty when the object covers less than this share of what it covers
# in the training images: candidate poses look at the same object from the same distances, so
# a render with under a tenth of its usual extent has lost it there.
UNTRAINED_EMPTY_SHARE = 0.1

# The tests, in the order `Health.reason` reports the first that failed.
REASONS = {
    "transparent": "renders its training views as background only, the object's pixels transparent",
    "blank": "renders its training views as background only, no closer to them than a blank image",
    "flat": "renders its training views without structure, no closer to them than their mean colour",
}


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
        mean_psnr: each image's mean colour, everywhere, against them, in dB (>= blank_psnr).
            None in records made before it was measured.
        untrained_views: how many untrained poses were rendered (0: none).
        untrained_empty: how many of those rendered the object on under `UNTRAINED_EMPTY_SHARE`
            of its share of the training images (None: none rendered).
        untrained_object_fraction: the share of their pixels rendered unlike the background.
        untrained_opacity: their mean rendered opacity over all pixels.
    """

    object_fraction: float
    object_opacity: float
    psnr: float
    blank_psnr: float
    views: int
    mean_psnr: float | None = None
    untrained_views: int = 0
    untrained_empty: int | None = None
    untrained_object_fraction: float | None = None
    untrained_opacity: float | None = None

    @property
    def reason(self) -> str | None:
        """The first test failed ("transparent", "blank", "flat": `REASONS`), None when none did.
        Images without an object never fail."""
        if self.object_fraction <= 0.0:
            return None
        if self.object_opacity < MIN_OBJECT_OPACITY:
            return "transparent"
        if self.psnr < self.blank_psnr + MIN_GAIN_DB:
            return "blank"
        if self.mean_psnr is not None and self.psnr < self.mean_psnr + MIN_GAIN_DB:
            return "flat"
        return None

    @property
    def empty(self) -> bool:
        """Whether the NeRF learned nothing of its training views (some test failed: `reason`)."""
        return self.reason is not None

    def untrained_line(self) -> str:
        """What the renders of the untrained poses showed, in words ("" when none were rendered)."""
        if not self.untrained_views:
            return ""
        return (
            f"{self.untrained_empty} of {self.untrained_views} untrained poses rendered empty (the object covers "
            f"{self.untrained_object_fraction:.0%} of their pixels, {self.object_fraction:.0%} of the training "
            f"images'; opacity {self.untrained_opacity:.2f})"
        )

    def line(self) -> str:
        """The finding in one line: which test failed and what to do when the NeRF is empty."""
        mean = "" if self.mean_psnr is None else f", {self.mean_psnr:.2f} dB for their mean colour"
        measured = (
            f"opacity {self.object_opacity:.3f} over the object's pixels, PSNR {self.psnr:.2f} dB against "
            f"{self.blank_psnr:.2f} dB for a blank image{mean}, on {self.views} training views"
        )
        untrained = self.untrained_line()
        measured += f"; {untrained}" if untrained else ""
        reason = self.reason
        if reason is None:
            return f"the NeRF learned its views ({measured})"
        return (
            f"the NeRF {REASONS[reason]} ({reason}: {measured}): train longer, with another --seed, or with "
            "another --engine (nerfacto-cpu) before asking it which views to capture"
        )

    def to_dict(self) -> dict:
        """The fields, with "empty" and "reason"; nan (no object pixels) as None, for JSON."""
        fields = {k: None if isinstance(v, float) and math.isnan(v) else v for k, v in asdict(self).items()}
        return {**fields, "empty": self.empty, "reason": self.reason}

    @classmethod
    def from_dict(cls, record: dict) -> Health:
        """The `Health` a `to_dict` (or an older record, without the later fields) describes."""
        known = {k: record[k] for k in cls.__dataclass_fields__ if k in record}
        if known.get("object_opacity") is None:
            known["object_opacity"] = math.nan
        return cls(**known)


def _psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    return -10.0 * math.log10(max(float((a - b).square().mean()), 1e-10))


def image_baselines(targets: torch.Tensor, background=(1.0, 1.0, 1.0)) -> tuple[float, float]:
    """The PSNR (dB) of the two images without structure against `targets` (n, H, W, 3): the
    blank image of `background`, and each image's own mean colour."""
    colour = torch.as_tensor(background, dtype=targets.dtype).reshape(1, 1, 3)
    mean = targets.mean(dim=(1, 2), keepdim=True).expand_as(targets)
    return _psnr(colour.expand_as(targets), targets), _psnr(mean, targets)


def health_targets(views) -> tuple[list[int], torch.Tensor]:
    """Which of `views` the check renders (up to `HEALTH_VIEWS`, spread over them) and their
    images shrunk to `HEALTH_WIDTH` pixels across: (indices, images (n, h, w, 3) on the CPU)."""
    from nerfaug.data.views import spread_over_frames

    chosen = spread_over_frames(min(HEALTH_VIEWS, len(views)), len(views))
    cameras = views.cameras
    width = min(HEALTH_WIDTH, cameras.width)
    height = max(1, round(width * cameras.height / cameras.width))
    targets = []
    for index in chosen:
        image = views.image(index).float().cpu()
        # Area averaging: each small pixel is the mean of the image pixels it covers.
        target = torch.nn.functional.interpolate(image.permute(2, 0, 1)[None], (height, width), mode="area")
        targets.append(target[0].permute(1, 2, 0))
    return chosen, torch.stack(targets)


def model_health(model, views, background=(1.0, 1.0, 1.0), untrained=None) -> Health:
    """Render up to `HEALTH_VIEWS` of `views` (a NeRF's training views) `HEALTH_WIDTH` pixels
    across with `model` and measure what it learned (`Health`).

    Args:
        model: a `NerfModel`, or anything with its `background` (a tensor on the model's device)
            and `render_image(cameras, index)` -> {"rgb": (H, W, 3), "accumulation": (H, W)}.
        views: `Views` with images (n, H, W, 3) in [0, 1], composited over `background`.
        background: the colour the images were composited over (RGB in [0, 1]).
        untrained: `Cameras` the NeRF did not train on (e.g. a proposal's candidates), or None;
            up to `UNTRAINED_VIEWS` of them, spread over them, are rendered at the same size.
    """
    device = model.background.device
    chosen, target = health_targets(views)
    height, width = target.shape[1:3]
    small = views.cameras.resized(width, height)
    colour = torch.as_tensor(background, dtype=torch.float32).reshape(1, 1, 3)
    renders, opacities = [], []
    for index in chosen:
        out = model.render_image(small.to(device), index)
        renders.append(out["rgb"].clamp(0, 1).cpu())
        opacities.append(out["accumulation"].cpu())
    render, opacity = torch.stack(renders), torch.stack(opacities)
    objects = (target - colour).abs().amax(dim=-1) > OBJECT_DIFFERENCE
    fraction = float(objects.float().mean())
    object_opacity = float(opacity[objects].mean()) if bool(objects.any()) else math.nan
    blank_psnr, mean_psnr = image_baselines(target, background)
    measured = Health(fraction, object_opacity, _psnr(render, target), blank_psnr, len(chosen), mean_psnr)
    if untrained is None or len(untrained) == 0:
        return measured
    return _with_untrained(measured, model, untrained, colour, width)


def _with_untrained(measured: Health, model, untrained, colour, width: int) -> Health:
    """`measured` with the renders of up to `UNTRAINED_VIEWS` of `untrained` (`Cameras`)."""
    from dataclasses import replace

    from nerfaug.data.views import spread_over_frames

    device = model.background.device
    height = max(1, round(width * untrained.height / untrained.width))
    small = untrained.resized(width, height)
    shares, opacities = [], []
    for index in spread_over_frames(min(UNTRAINED_VIEWS, len(untrained)), len(untrained)):
        out = model.render_image(small.to(device), index)
        shown = (out["rgb"].clamp(0, 1).cpu() - colour[0]).abs().amax(dim=-1) > OBJECT_DIFFERENCE
        shares.append(float(shown.float().mean()))
        opacities.append(float(out["accumulation"].float().mean()))
    empty = sum(share < UNTRAINED_EMPTY_SHARE * measured.object_fraction for share in shares)
    return replace(
        measured,
        untrained_views=len(shares),
        untrained_empty=int(empty),
        untrained_object_fraction=sum(shares) / len(shares),
        untrained_opacity=sum(opacities) / len(opacities),
    )
