"""CLI commands of the active-capture loop (`nerfaug.capture`): train, propose, add, export, and
render-proposals (a simulated capture with Blender).

    nerfaug train DATA --out RUN --steps 1000      start a session on the views you have
    nerfaug propose RUN --n 6 --out poses.json     where to capture next (+ poses.png, the map)
    nerfaug add RUN --images DIR --poses poses.json --steps 1000
    nerfaug train RUN --steps 1000                 train an existing session further
    nerfaug export RUN --format nerfstudio --out DIR
    nerfaug eval RUN --data DATASET --split test   PSNR/SSIM/LPIPS on held-out views
"""

from __future__ import annotations

import contextlib
import sys
import warnings
from pathlib import Path
from time import monotonic
from typing import Annotated, Literal

import tyro

from nerfaug import serve_cli
from nerfaug.capture.constraints import ViewConstraints
from nerfaug.capture.state import SESSION_FILE, DuplicateViews, SessionState, UnverifiedCheckpoint
from nerfaug.cli_hints import none_means
from nerfaug.cli_options import COMMAND_LINE, given_options
from nerfaug.data.formats import EXCHANGE_FORMAT, FORMATS
from nerfaug.experiment.config import ExperimentConfig
from nerfaug.nerf.config import EnginePreset
from nerfaug.selection.config import SelectionConfig

RunFolder = Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="RUN")]
Device = Literal["auto", "cpu", "cuda"]
FormatName = Literal[tuple(FORMATS)]  # the registered dataset formats' names
# The defaults `--selection.*` options start from (read-only use: never mutated).
DEFAULT_SELECTION = SelectionConfig()
DEFAULT_CONSTRAINTS = ViewConstraints()


def _device(device: str) -> str:
    """`device` resolved (auto -> cuda or cpu), or exit with one line saying why it cannot be used."""
    from nerfaug.device import resolve_device

    try:
        return str(resolve_device(device))
    except ValueError as error:
        raise SystemExit(f"--device: {error}") from None


def _open(run: Path, device: str, changing: str | None = None):
    """The session in `run`; `changing` (the command, e.g. "train") locks it first until the
    command ends, waiting for another command that changes it (`nerfaug.capture.lock`)."""
    from nerfaug.capture import CaptureSession

    if changing is not None:
        _lock(run, changing)
    with _warning_lines():
        return CaptureSession.open(run, device=_device(device), progress=True)


def _lock(run: Path, command: str) -> None:
    from nerfaug.capture.lock import hold

    if (run / SESSION_FILE).is_file():  # else open() says what is wrong with the folder
        hold(run, f"nerfaug {command}", on_wait=lambda line: print(line, file=sys.stderr, flush=True))


# `nerfaug train` and `add` save the session this often (seconds of training; a killed command
# loses at most this much), at the end, and when Ctrl-C stops them.
CHECKPOINT_EVERY_S = 60.0
_CHUNK = 10  # steps between checks for Ctrl-C and the clock
# Torch threads of a session's training: a sweep's policy (one per run unless told), so a session
# and a study sharing a machine do not oversubscribe its cores.
THREADS = ExperimentConfig.__dataclass_fields__["threads_per_run"].default


def _configure(threads: int) -> None:
    from nerfaug.device import configure_process

    if threads < 1:
        raise ValueError(f"--threads {threads}: must be >= 1 (torch threads)")
    configure_process(threads=threads)


@contextlib.contextmanager
def _warning_lines():
    """Show the capture's warnings (`DuplicateViews`, `UnverifiedCheckpoint`) as one line each,
    `warning: ...` on stderr."""
    with warnings.catch_warnings():
        warnings.simplefilter("always", DuplicateViews)
        warnings.simplefilter("always", UnverifiedCheckpoint)
        default = warnings.showwarning

        def show(message, category, filename, lineno, file=None, line=None):
            if issubclass(category, (DuplicateViews, UnverifiedCheckpoint)):
                print(f"warning: {message}", file=sys.stderr)
            else:
                default(message, category, filename, lineno, file, line)

        warnings.showwarning = show
        yield


@contextlib.contextmanager
def _as_options():
    """Show a library's `RequestError` as this command's option: `--n-candidates 0: must be >= 1`."""
    from nerfaug.capture.requests import RequestError

    try:
        yield
    except RequestError as error:
        raise ValueError(f"--{error.argument.replace('_', '-')} {error.value}: {error.problem}") from None


def _check_steps(steps: int) -> None:
    from nerfaug.capture.requests import check_steps

    with _as_options():
        check_steps(steps)


def _check_period(seconds: float) -> None:
    if not seconds > 0:
        raise ValueError(f"--checkpoint-every {seconds}: must be > 0 (seconds between saves)")


def _train(session, steps: int, every_s: float = CHECKPOINT_EVERY_S) -> dict:
    """Train `steps` more steps, saving once `every_s` seconds passed since the last save, and at
    the end. A first Ctrl-C stops at the next step boundary and saves; a second stops at once,
    keeping the last save.

    Raises:
        Interrupted: after Ctrl-C, saying at which step the session was saved.
    """
    import signal

    from nerfaug.errors import Interrupted
    from nerfaug.progress import progress_bar

    asked = []

    def stop(signum, frame):
        if asked:
            raise KeyboardInterrupt
        asked.append(signum)
        print("stopping after the current steps to save the session (Ctrl-C again: stop at once)", file=sys.stderr)

    show, session.trainer.progress = session.trainer.progress, False  # one bar over the chunks
    target, saved, last = session.step + steps, session.step, {"step": session.step}
    saved_at = monotonic()
    previous = signal.signal(signal.SIGINT, stop)
    bar = progress_bar(fields="psnr {psnr:.2f} dB", enabled=show)
    try:
        with bar:
            task = bar.add_task("training", total=steps, psnr=float("nan"))
            while session.step < target and not asked:
                last = session.train(min(_CHUNK, target - session.step))
                bar.update(task, completed=steps - (target - session.step), psnr=last.get("psnr", float("nan")))
                if monotonic() - saved_at >= every_s:
                    session.save()
                    saved, saved_at = session.step, monotonic()
        session.save()
    except KeyboardInterrupt:
        raise Interrupted(
            f"{session.run_dir}: interrupted at step {session.step}; the session saved at step {saved} "
            f"is kept (`nerfaug train {session.run_dir}` goes on from there)"
        ) from None
    finally:
        signal.signal(signal.SIGINT, previous)
        session.trainer.progress = show
    if asked:
        raise Interrupted(
            f"{session.run_dir}: interrupted; the session is saved at step {session.step} "
            f"(`nerfaug train {session.run_dir}` goes on from there)"
        )
    return last


def _create(data: Path, out: Path, split: str | None, **options):
    """A new session on `data` in `out`, after one line saying how many views it trains on and why."""
    from nerfaug.capture import CaptureSession
    from nerfaug.capture.dataset import default_split
    from nerfaug.data import load_dataset

    why = f"split '{split}' of {data}"
    if split is None:
        split, why = default_split(data)
    print(f"training on {len(load_dataset(data, split, lazy=True))} views: {why}", flush=True)
    with _warning_lines(), _as_options():
        session = CaptureSession.create(data, out, split=split, progress=True, **options)
    _lock(out, "train")
    h = session.hemisphere
    print(
        f"session created in {out}: {len(session.trainer.train_views)} views; hemisphere centre "
        f"{[round(c, 4) for c in h.centre]}, radius {h.radius:.4g}, up {[round(u, 4) for u in h.up]}"
    )
    return session


def train(
    path: Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="DATA|RUN")],
    out: Annotated[
        Path | None, tyro.conf.arg(metavar="PATH", help_behavior_hint="(required when PATH is a dataset)")
    ] = None,
    steps: int = 1000,
    preset: EnginePreset = "cpu",
    seed: int = 0,
    split: Annotated[
        str | None, none_means('"initial" for a dataset `nerfaug scene render` wrote, else "train"', "STR")
    ] = None,
    downscale: int = 1,
    centre: Annotated[tuple[float, float, float] | None, none_means("the point the cameras look at", "X Y Z")] = None,
    radius: Annotated[float | None, none_means("the cameras' mean distance to the centre", "FLOAT")] = None,
    up: tuple[float, float, float] = (0.0, 0.0, 1.0),
    estimate_up: bool = False,
    device: Device = "auto",
    checkpoint_every: float = CHECKPOINT_EVERY_S,
    threads: int = THREADS,
) -> None:
    """Start an active-capture session on a dataset and train it, or train an existing session further.

    Given a dataset, `nerfaug train DATA --out RUN` copies its views into RUN/dataset, builds the NeRF
    and trains it; given a run folder (one holding session.json), `nerfaug train RUN` trains `--steps` more.

    Args:
        path: a Blender (transforms_{split}.json) or nerfstudio (transforms.json) dataset folder,
            or an existing run folder.
        out: the run folder to create.
        steps: training steps to run now.
        preset: NeRF engine preset (new sessions only).
        seed: seeds the model, its training and every proposal (new sessions only).
        split: the Blender split holding the captured views (a dataset `nerfaug scene render`
            wrote keeps its candidate pool in "train").
        downscale: train on images shrunk by this integer factor.
        centre: the hemisphere's centre, world space.
        radius: the hemisphere's radius.
        up: the hemisphere's pole direction, world space (the world is z-up by default).
        estimate_up: take the pole from the cameras' mean up axis instead of --up.
        device: where the NeRF trains: auto (cuda when this machine has a GPU, else cpu), cpu, cuda.
        checkpoint_every: save the session after this many seconds of training (and at the end).
        threads: torch threads for training (as a sweep's runs: one by default).
    """
    _check_steps(steps)
    _check_period(checkpoint_every)
    _configure(threads)
    if (path / SESSION_FILE).exists():
        if out is not None:
            raise SystemExit(f"{path} is already a session folder; drop --out to train it further")
        differs = {  # from Python (no command line): what differs from the defaults
            "preset": preset != "cpu",
            "seed": seed != 0,
            "split": split is not None,
            "downscale": downscale != 1,
            "centre": centre is not None,
            "radius": radius is not None,
            "up": tuple(up) != (0.0, 0.0, 1.0),
            "estimate-up": estimate_up,
        }
        argv = COMMAND_LINE.get()
        # On the command line an option given at its default is given all the same.
        given = given_options(list(differs), argv) if argv is not None else {k for k, v in differs.items() if v}
        if given:
            options = ", ".join(f"--{name}" for name in differs if name in given)
            raise ValueError(
                f"{options}: only for a new session; {path / SESSION_FILE} keeps this session's "
                "settings, so drop them (or start a new session with `nerfaug train DATA --out NEW_RUN`)"
            )
        session = _open(path, device, changing="train")
        print(f"training {path} further: {len(session.trainer.train_views)} views, from step {session.step}")
    else:
        if out is None:
            raise SystemExit(f"{path} is a dataset: give the run folder to create with --out RUN")
        session = _create(
            path,
            out,
            preset=preset,
            seed=seed,
            split=split,
            centre=centre,
            radius=radius,
            up="estimate" if estimate_up else up,
            downscale=downscale,
            device=_device(device),
        )
    last = _train(session, steps, checkpoint_every)
    psnr = f", training PSNR {last['psnr']:.2f} dB" if "psnr" in last else ""
    print(f"{session.run_dir}: step {session.step}{psnr}")


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
    azimuth, polar, score}]}) holds world-frame OpenGL camera-to-world poses, ready for a robot or
    Blender, with azimuth and polar in radians (printed here in degrees); the hemisphere map of
    every candidate's score is written beside it (same name, .png). Name each captured image after
    its frame's file_path (e.g. capture_000_00.png) for `nerfaug add`.

    Args:
        run: the session's run folder.
        n: views to propose.
        method: the selection method (`nerfaug methods`); "ours" is the paper's entropy + coverage
            with each term min-max normalised, then rejection sampling ("ours-paper-sum": the raw
            sum as the paper writes it). Which method to use, by the study (docs/results.md, "Which
            method to use"): on the nerfacto-cpu engine, ours-batch-sharp beat uniform across the
            scenes, by under 1 dB; on the cpu engine (the default) and on the
            nerfacto-cpu-last-sample engine (nerfacto's "last_sample" background) no method did,
            and uniform is as good a choice there; spatial entropy was worse than uniform on every
            engine measured. The paper engine (GPU) is not measured yet.
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
    for name, a, p in zip(proposal.names, proposal.azimuth.tolist(), proposal.polar.tolist()):
        print(f"  {name}: azimuth {a * 57.29578:6.1f} deg, polar {p * 57.29578:5.1f} deg")


def add(
    run: RunFolder,
    images: Path,
    poses: Path,
    steps: int = 1000,
    device: Device = "auto",
    checkpoint_every: float = CHECKPOINT_EVERY_S,
    threads: int = THREADS,
) -> None:
    """Add captured images at the poses of a poses JSON, then train on.

    Each frame of the JSON is matched to the image in --images whose file name (without
    extension) is the frame's file_path stem. Everything is checked before anything is written:
    on an error the dataset is left as it was.

    Args:
        run: the session's run folder.
        images: folder holding the captured images (PNG, JPEG, ...).
        poses: the poses JSON (as `nerfaug propose` writes it, or your robot's actual poses in
            the same format).
        steps: training steps to run after adding (0: add only).
        device: where the NeRF trains: auto (cuda when available, else cpu), cpu, cuda.
        checkpoint_every: save the session after this many seconds of training (and at the end).
        threads: torch threads for training (as a sweep's runs: one by default).
    """
    _check_steps(steps)  # before anything is written: a refused call changes nothing
    _check_period(checkpoint_every)
    _configure(threads)
    session = _open(run, device, changing="add")
    with _warning_lines():
        names = session.add_views(images, poses)
    session.save()  # the addition's record is kept even if training is stopped at once
    print(
        f"added {len(names)} views ({', '.join(names)}); the dataset now has {len(session.trainer.train_views)} views"
    )
    last = _train(session, steps, checkpoint_every)
    if steps:
        print(f"step {session.step}, training PSNR {last['psnr']:.2f} dB")


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
