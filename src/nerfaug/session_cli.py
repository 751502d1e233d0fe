"""CLI commands of the active-capture loop (`nerfaug.capture`): propose, export, eval and
render-proposals (a simulated capture with Blender); `train` and `add`, the commands that train,
are in `nerfaug.train_cli`.

    nerfaug train DATA --out RUN --steps 1000      start a session on the views you have
    nerfaug propose RUN --n 6 --out poses.json     where to capture next (+ poses.png, the map)
    nerfaug add RUN --images DIR --poses poses.json --steps 1000
    nerfaug train RUN --steps 3000                 train an existing session until step 3000
    nerfaug export RUN --format nerfstudio --out DIR
    nerfaug eval RUN --data DATASET --split test   PSNR/SSIM/LPIPS on held-out views
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Literal

import tyro

from nerfaug import serve_cli
from nerfaug.capture.constraints import ViewConstraints
from nerfaug.capture.state import SessionState
from nerfaug.cli_hints import none_means
from nerfaug.data.formats import EXCHANGE_FORMAT, FORMATS
from nerfaug.selection.config import SelectionConfig
from nerfaug.train_cli import THREADS, Device, RunFolder, _as_options, _configure, _open, add, train

FormatName = Literal[tuple(FORMATS)]  # the registered dataset formats' names
# The defaults `--selection.*` options start from (read-only use: never mutated).
DEFAULT_SELECTION = SelectionConfig()
DEFAULT_CONSTRAINTS = ViewConstraints()


def propose(
    run: RunFolder,
    n: int = 6,
    method: str = "ours",
    out: Path = Path("poses.json"),
    candidates: Annotated[
        Path | None, tyro.conf.arg(metavar="PATH", help_behavior_hint="(default: the hemisphere)")
    ] = None,
    n_candidates: int = 500,
    seed: Annotated[
        int | None, tyro.conf.arg(metavar="INT", help_behavior_hint="(default: the session's, per proposal)")
    ] = None,
    device: Device = "auto",
    selection: SelectionConfig = DEFAULT_SELECTION,
    constraints: Annotated[ViewConstraints, tyro.conf.OmitArgPrefixes] = DEFAULT_CONSTRAINTS,
    min_separation: float = 0.0,
    force: bool = False,
    threads: int = THREADS,
) -> None:
    """Propose the next views to capture and write their poses as a Blender-style JSON.

    The JSON ({camera_angle_x, w, h, fl_x, fl_y, cx, cy, frames: [{file_path, transform_matrix,
    azimuth, elevation, score}]}) holds world-frame OpenGL camera-to-world poses, ready for a robot
    or Blender, with azimuth and elevation in radians (printed here in degrees); the hemisphere map of
    every candidate's score is written beside it (same name, .png). Name each captured image after
    its frame's file_path (e.g. capture_000_00.png) for `nerfaug add`.

    Args:
        run: the session's run folder.
        n: views to propose.
        method: the selection method (`nerfaug methods` lists them); "ours" is the paper's: how
            unsure the NeRF is about a view plus how far it is from the views trained on, then
            random draws in proportion to that score. Which method to use on which engine, as
            measured: docs/methods.md.
        out: the poses JSON to write.
        candidates: a transforms JSON of reachable poses (e.g. a robot's workspace) to choose
            from instead of the hemisphere.
        n_candidates: hemisphere candidates to score.
        seed: seed this proposal explicitly; by default it comes from the session seed and the
            proposal number, so the same session state always proposes the same views.
        device: where candidates are scored: auto (cuda when available, else cpu), cpu, cuda.
        selection: options of the selection method (recorded with the proposal in session.json);
            a method's own settings (e.g. ours-authors') apply over them.
        constraints: where views may lie (--elevation, --azimuth, --radius, --keep-out), applied
            to the hemisphere's candidates or to --candidates.
        min_separation: keep every two proposed views at least this many degrees apart, seen
            from the hemisphere's centre (0: off, the method's own choice).
        force: overwrite --out (and its .png) even when nerfaug did not write it, or it was edited
            (never inside a capture session's folder: its proposals are its own record).
        threads: torch threads for scoring the candidates.
    """
    from nerfaug.capture.choose import ProposalRequest
    from nerfaug.capture.proposal import check_poses_out

    request = ProposalRequest(
        n,
        method,
        candidates=candidates,
        n_candidates=n_candidates,
        seed=seed,
        config=selection,
        constraints=constraints,
        min_separation=min_separation,
    )
    with _as_options():
        request = request.checked()  # before the session is opened: a refused call loads nothing
    check_poses_out(out, force)
    _configure(threads)
    session = _open(run, device, changing="propose")
    proposal = session.propose(
        request.n,
        request.method,
        candidates=request.candidates,
        n_candidates=request.n_candidates,
        seed=request.seed,
        config=request.config,
        constraints=request.constraints,
        min_separation=request.min_separation,
    )
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
    from nerfaug.capture import CaptureSession

    session = CaptureSession.open(run, load_model=False)  # exporting reads only the dataset folder
    path = session.export(out, format)
    print(f"exported {len(session.cameras)} views to {path}")


EVAL_KIND = "session-eval"  # the key marking a JSON `nerfaug eval` wrote (and may overwrite)


def _check_eval_out(out: Path, data: Path) -> None:
    """Refuse an --out inside the dataset, or over a file that `nerfaug eval` did not write."""
    import json

    from nerfaug import owned
    from nerfaug.errors import FolderRefused

    if owned.overlaps(out, data):
        raise FolderRefused(f"{out}: lies inside the dataset {data}; nothing is written into an input folder")
    if out.exists():
        try:
            ours = json.loads(out.read_text()).get("nerfaug", {}).get("kind") == EVAL_KIND
        except (OSError, ValueError, AttributeError):
            ours = False
        if not ours:
            raise FolderRefused(
                f"{out}: exists and is not an evaluation nerfaug wrote, so it is not overwritten; choose another --out"
            )


def _metric(value, digits: int) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def evaluate(
    run: RunFolder,
    data: Path,
    split: str = "test",
    out: Annotated[Path | None, none_means("print only", "PATH")] = None,
    lpips: bool = True,
    device: Device = "auto",
    threads: int = THREADS,
) -> None:
    """Score the session's NeRF on held-out views: PSNR, SSIM and LPIPS of its renders against
    a dataset split, at the session's training resolution (as nerfstudio's ns-eval).

    Args:
        run: the session's run folder.
        data: a dataset folder of the same scene and world frame (e.g. the one the session started from).
        split: the split to score ("test": a dataset `nerfaug scene render` wrote has 200 held-out views).
        out: write the metrics, mean and per view, to this JSON file.
        lpips: compute LPIPS (when its weights are installed; otherwise reported as n/a).
        device: where the NeRF renders: auto (cuda when available, else cpu), cpu, cuda.
        threads: torch threads for rendering and scoring.
    """
    from nerfaug import __version__
    from nerfaug.jsonio import atomic_write_json

    if out is not None:
        _check_eval_out(out, data)
    _configure(threads)
    session = _open(run, device)
    views = session.held_out(data, split)
    result = session.evaluate(views, lpips="auto" if lpips else None, progress=True)
    m = result.mean
    print(f"{run} (step {session.step}) on split '{split}' of {data}: {len(views)} views")
    print(f"  PSNR {_metric(m['psnr'], 2)} dB   SSIM {_metric(m['ssim'], 4)}   LPIPS {_metric(m['lpips'], 4)}")
    if m["lpips"] is None:
        print(f"  LPIPS {result.lpips_status}")
    if out is not None:
        record = {
            "nerfaug": {"kind": EVAL_KIND, "version": __version__},
            "session": str(run),
            "step": session.step,
            "data": str(data),
            "split": split,
            **result.to_dict(),
        }
        atomic_write_json(out, record)
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
    from nerfaug.capture import read_poses
    from nerfaug.scenes.render import render_poses

    for name, value in (("samples", samples), ("threads", threads)):
        if value < 1:
            raise ValueError(f"--{name} {value}: must be >= 1")
    if seed < 0:
        raise ValueError(f"--seed {seed}: must be >= 0")
    k = SessionState.read(run).intrinsics
    if abs(k.fx - k.fy) > 1e-3 * k.fx:
        raise SystemExit("Blender renders square pixels; this session's camera has fx != fy")
    matrices, names = read_poses(poses)
    paths = [out / f"{name}.png" for name in names]
    render_poses(scene, matrices, paths, k.width, k.height, k.camera_angle_x, samples, seed, threads)
    print(f"rendered {len(paths)} views to {out}")


COMMANDS: dict = {
    "train": train,
    "propose": propose,
    "add": add,
    "export": export,
    "eval": evaluate,
    "render-proposals": render_proposals,
    **serve_cli.COMMANDS,
}
