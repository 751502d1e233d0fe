"""CLI commands of the active-capture loop (`nerfaug.capture`): propose, export, eval and
render-proposals (a simulated capture with Blender); `train` and `add`, the commands that train,
are in `nerfaug.cli.train`.

    nerfaug train DATA --out RUN --steps 1000      start a session on the views you have
    nerfaug propose RUN --n 6 --out poses.json     where to capture next (+ poses.png, the map)
    nerfaug add RUN --images DIR --poses poses.json --steps 1000
    nerfaug train RUN --steps 3000                 train an existing session until step 3000
    nerfaug export RUN --format nerfstudio --out DIR
    nerfaug eval RUN                               PSNR/SSIM/LPIPS on held-out views

Here are their options and help; their work, which loads torch, is `nerfaug.cli.session_work`,
imported when a command runs, so that `--help` answers at once.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

import tyro

from nerfaug.capture.proposal_request import ProposalRequest
from nerfaug.capture.requests import replaced_by
from nerfaug.cli.train import THREADS, RunFolder
from nerfaug.device_choice import Device

# The registered dataset formats' names (`nerfaug.data.formats.FORMATS`, which loads torch:
# tests/cli/test_help.py checks that the two agree) and the one an export writes by default.
FormatName = Literal["blender", "nerfstudio", "idr", "llff"]
EXCHANGE_FORMAT = "nerfstudio"
Request = Annotated[ProposalRequest, tyro.conf.arg(name="")]


def propose(
    run: RunFolder,
    request: Request = ProposalRequest(),  # noqa: B008 -- read-only: the defaults tyro shows
    out: Path = Path("poses.json"),
    device: Device = "auto",
    force: bool = False,
    threads: int = THREADS,
) -> None:
    """Propose the next views to capture and write their poses as a Blender-style JSON.

    The JSON ({camera_angle_x, w, h, fl_x, fl_y, cx, cy, frames: [{file_path, transform_matrix,
    azimuth, elevation, score}]}) holds world-frame OpenGL camera-to-world poses, ready for a robot
    or Blender, with azimuth and elevation in radians (printed here in degrees); the hemisphere map of
    every candidate's score is written beside it (same name, .png). Name each captured image after
    its frame's file_path (e.g. capture_000_00.png) for `nerfaug add`. Which method to use on which
    engine, as measured: docs/methods.md.

    Args:
        run: the session's run folder.
        out: the poses JSON to write.
        device: where candidates are scored.
        force: overwrite --out (and its .png) even when nerfaug did not write it, or it was edited
            (never inside a capture session's folder: its proposals are its own record).
        threads: torch threads for scoring the candidates.
    """
    from nerfaug.cli import session_work  # torch: here, so that `nerfaug propose --help` loads none

    session_work.propose(run, request, out, device, force, threads)


def export(
    run: RunFolder,
    out: Path,
    format: FormatName = EXCHANGE_FORMAT,
) -> None:
    """Write the session's grown dataset for other tools.

    nerfstudio: transforms.json + images/ (opens in nerfstudio, `ns-train nerfacto --data OUT`,
    and instant-ngp). blender: transforms_train.json + train/*.png (NeRF-synthetic), with the
    source dataset's val/test splits when it has them.

    Args:
        run: the session's run folder.
        out: the folder to write.
        format: the dataset format to write.
    """
    from nerfaug.cli import session_work  # torch: here, so that `nerfaug export --help` loads none

    session_work.export(run, out, format)


def evaluate(
    run: RunFolder,
    data: Annotated[Path | None, replaced_by("the dataset the session started from", "PATH")] = None,
    split: Annotated[str | None, replaced_by("its held-out views", "SPLIT")] = None,
    out: Annotated[Path | None, replaced_by("print only", "PATH")] = None,
    lpips: bool = True,
    device: Device = "auto",
    threads: int = THREADS,
) -> None:
    """Score the session's NeRF on held-out views: PSNR, SSIM and LPIPS of its renders against
    them, at the session's training resolution (as nerfstudio's ns-eval). A session started with
    --initial from a set without a test split (LLFF, DTU, nerfstudio) is scored on the views it kept
    apart; any other on a dataset split. A view with the pose of one the session trains on is
    marked in the JSON and counted in a warning.

    Args:
        run: the session's run folder.
        data: a dataset folder of the same scene and world frame (default: the one the session started from).
        split: the split to score (default: the views the session's start kept apart, else "test": a
            dataset `nerfaug scene render` wrote has 200 held-out views).
        out: write the metrics, mean and per view, to this JSON file.
        lpips: compute LPIPS (when its weights are installed; otherwise reported as n/a).
        device: where the NeRF renders.
        threads: torch threads for rendering and scoring.
    """
    from nerfaug.cli import session_work  # torch: here, so that `nerfaug eval --help` loads none

    session_work.evaluate(run, data, split, out, lpips, device, threads)


def render_proposals(
    run: RunFolder,
    poses: Path,
    scene: str,
    out: Path,
    samples: int = 16,
    seed: int = 0,
    threads: int = 2,
) -> None:
    """Capture proposed poses in simulation: render them with Blender, one PNG per frame named
    after its file_path stem, ready for `nerfaug add RUN --images OUT --poses POSES`.

    Args:
        run: the session's run folder (for the camera's intrinsics and image size).
        poses: the poses JSON `nerfaug propose` wrote.
        scene: a built-in scene (lego, chair, materials, cow) or a .blend file.
        out: folder to write the renders to.
        samples: Cycles samples per pixel.
        seed: Cycles noise seed.
        threads: CPU threads for Cycles.
    """
    from nerfaug.cli import session_work  # torch: here, so that `--help` loads none

    session_work.render_proposals(run, poses, scene, out, samples, seed, threads)
