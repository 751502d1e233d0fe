"""The CLI command that draws uncertainty images of any view of a capture session.

    nerfaug uncertainty RUN --poses POSES.json --out DIR

Its work, which loads torch and matplotlib, is `nerfaug.cli.uncertainty_work`, imported when the
command runs, so that `--help` answers at once.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import tyro

from nerfaug import owned
from nerfaug.capture.requests import FISHER_WIDTH, check_image_widths, check_threads, replaced_by
from nerfaug.cli.option_names import as_options
from nerfaug.device_choice import Device
from nerfaug.errors import FolderRefused

UNCERTAINTY_KIND = "uncertainty-images"  # the marker of a folder `nerfaug uncertainty` wrote


def uncertainty(
    run: Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="RUN")],
    poses: Path,
    out: Path,
    width: Annotated[int | None, replaced_by("the training resolution", "INT")] = None,
    fisher: bool = True,
    fisher_width: int = FISHER_WIDTH,
    shared_scale: bool = True,
    device: Device = "auto",
    threads: int = 1,
) -> None:
    """Uncertainty images of any views of a session: for each pose of a poses JSON, what the NeRF
    renders, its depth, the ray entropy and FisherRF's per-pixel score, as NAME.png (panels with
    colour bars) and NAME_rgb.npy, NAME_depth.npy, NAME_opacity.npy, NAME_entropy.npy,
    NAME_fisher.npy, NAME_pose.npy. In the figures, depth is drawn only where the rays are mostly
    opaque (grey: background), and FisherRF's log scale spans the top four decades.

    Args:
        run: the session's run folder.
        poses: a transforms JSON of world-frame poses (e.g. what `nerfaug propose` wrote); files are
            named after its frames' file_path.
        out: the folder to write (new, empty, or one this command wrote before).
        width: pixels across of the render, depth and entropy.
        fisher: also compute FisherRF's per-pixel score (three backward passes per pixel).
        fisher_width: pixels across of the FisherRF image.
        shared_scale: draw every view's figure on the same colour scales, so views compare by
            eye (--no-shared-scale: each figure spans its own values).
        device: where the NeRF renders.
        threads: torch threads (one is the fastest on a machine that runs other work).
    """
    _check_uncertainty(run, out, width, fisher_width, threads)
    from nerfaug.cli import uncertainty_work  # torch, matplotlib: here, so that `--help` loads neither

    uncertainty_work.uncertainty(
        run, poses, out, UNCERTAINTY_KIND, device, threads, (width, fisher, fisher_width), shared_scale
    )


def _check_uncertainty(run: Path, out: Path, width: int | None, fisher_width: int, threads: int) -> None:
    """`nerfaug uncertainty`'s options, checked before anything is read."""
    with as_options():
        check_image_widths(width, fisher_width)
        check_threads(threads)
    if not owned.is_empty(out) and not owned.marked(out, UNCERTAINTY_KIND):
        raise FolderRefused(f"{out}: not empty and not written by `nerfaug uncertainty`; choose a new folder for --out")
    if owned.overlaps(out, run):
        raise FolderRefused(f"{out}: lies inside or holds the session {run}; choose a folder outside it")
