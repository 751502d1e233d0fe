"""CLI commands of the active-capture loop (`nerfaug.capture`): propose, export, eval and
render-proposals (a simulated capture with Blender); `train` and `add`, the commands that train,
are in `nerfaug.cli.train`.

    nerfaug train DATA --out RUN --steps 1000      start a session on the views you have
    nerfaug propose RUN --n 6 --out poses.json     where to capture next (+ poses.png, the map)
    nerfaug add RUN --images DIR --poses poses.json --steps 1000
    nerfaug train RUN --steps 3000                 train an existing session until step 3000
    nerfaug export RUN --format nerfstudio --out DIR
    nerfaug eval RUN --data DATASET --split test   PSNR/SSIM/LPIPS on held-out views
"""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Annotated, Literal

import tyro

from nerfaug.capture.choose import ProposalRequest
from nerfaug.capture.evaluate import check_evaluation_out, trained_on_count, write_evaluation
from nerfaug.capture.folder import SessionFolder
from nerfaug.capture.proposal import check_poses_out
from nerfaug.capture.requests import replaced_by
from nerfaug.capture.simulate import render_proposals as simulated_capture
from nerfaug.cli.option_names import as_options, checked
from nerfaug.cli.train import THREADS, Device, RunFolder
from nerfaug.cli.train_work import configure, open_session, warning_lines
from nerfaug.data.formats import EXCHANGE_FORMAT, FORMATS

FormatName = Literal[tuple(FORMATS)]  # the registered dataset formats' names
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
        device: where candidates are scored: auto (cuda when available, else cpu), cpu, cuda.
        force: overwrite --out (and its .png) even when nerfaug did not write it, or it was edited
            (never inside a capture session's folder: its proposals are its own record).
        threads: torch threads for scoring the candidates.
    """
    request = checked(request)  # before the session is opened: a refused call loads nothing
    check_poses_out(out, force)
    configure(threads)
    session = open_session(run, device, changing="propose")
    with warning_lines():
        proposal = session.propose(request)
    path = proposal.write(out)
    session.save()
    print(
        f"proposal {proposal.number} ({proposal.method}, model at step {proposal.step}): {path} (angles in "
        f"radians), map {path.with_suffix('.png')}"
    )
    for name, a, e in zip(proposal.names, proposal.azimuth.tolist(), proposal.elevation.tolist()):
        print(f"  {name}: azimuth {math.degrees(a):6.1f} deg, elevation {math.degrees(e):5.1f} deg")


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
    folder = SessionFolder.open(run)  # exporting reads only the dataset folder
    path = folder.export(out, format)
    print(f"exported {folder.summary().views} views to {path}")


def _metric(value, digits: int) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def evaluate(
    run: RunFolder,
    data: Path,
    split: str = "test",
    out: Annotated[Path | None, replaced_by("print only", "PATH")] = None,
    lpips: bool = True,
    device: Device = "auto",
    threads: int = THREADS,
) -> None:
    """Score the session's NeRF on held-out views: PSNR, SSIM and LPIPS of its renders against
    a dataset split, at the session's training resolution (as nerfstudio's ns-eval). A view with
    the pose of one the session trains on is marked in the JSON and counted in a warning.

    Args:
        run: the session's run folder.
        data: a dataset folder of the same scene and world frame (e.g. the one the session started from).
        split: the split to score ("test": a dataset `nerfaug scene render` wrote has 200 held-out views).
        out: write the metrics, mean and per view, to this JSON file.
        lpips: compute LPIPS (when its weights are installed; otherwise reported as n/a).
        device: where the NeRF renders: auto (cuda when available, else cpu), cpu, cuda.
        threads: torch threads for rendering and scoring.
    """
    if out is not None:
        check_evaluation_out(out, data)
    configure(threads)
    session = open_session(run, device)
    views = session.held_out(data, split)
    result = session.evaluate(views, lpips="auto" if lpips else None, progress=True)
    m = result.mean
    print(f"{run} (step {session.step}) on split '{split}' of {data}: {len(views)} views")
    print(f"  PSNR {_metric(m['psnr'], 2)} dB   SSIM {_metric(m['ssim'], 4)}   LPIPS {_metric(m['lpips'], 4)}")
    if m["lpips"] is None:
        print(f"  LPIPS {result.lpips_status}")
    if trained := trained_on_count(result):
        print(
            f"warning: {trained} of the {len(views)} views have the pose of a view the session trains on, so "
            "they score how well it was fitted, not held-out views (a captured set keeps one listing: every "
            "--split of it is all of it)",
            file=sys.stderr,
        )
    if out is not None:
        write_evaluation(out, result, run, session.step, data, split)
        print(f"  written to {out}")


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
    with as_options():
        paths = simulated_capture(run, poses, scene, out, samples, seed, threads)
    print(f"rendered {len(paths)} views to {out}")
