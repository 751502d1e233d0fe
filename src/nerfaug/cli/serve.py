"""CLI commands for capturing with a robot: the HTTP service over capture sessions, and
uncertainty images of any view of a session.

    nerfaug serve --root SESSIONS                   the HTTP JSON service (API docs at /docs)
    nerfaug uncertainty RUN --poses POSES.json --out DIR

`--help` answers at once: torch, FastAPI and the capture core's sessions are imported inside the
commands (the service's packages are optional: `pip install 'nerfaug[serve]'`).
"""

from __future__ import annotations

import gc
import ipaddress
import logging
import os
import sys
from pathlib import Path
from typing import Annotated, Literal

import tyro

from nerfaug import owned
from nerfaug.capture.requests import CHECKPOINT_EVERY_S, replaced_by
from nerfaug.errors import FolderRefused

TOKEN_ENV = "NERFAUG_TOKEN"
UNCERTAINTY_KIND = "uncertainty-images"  # the marker of a folder `nerfaug uncertainty` wrote


def is_loopback(host: str) -> bool:
    """Whether `host` binds only this machine (127.0.0.0/8, ::1, localhost)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def serve(
    root: Path = Path("sessions"),
    host: str = "127.0.0.1",
    port: int = 8000,
    token: Annotated[str | None, replaced_by(f"the {TOKEN_ENV} environment variable, if set", "TOKEN")] = None,
    device: Literal["auto", "cpu", "cuda"] = "auto",
    checkpoint_every: float = CHECKPOINT_EVERY_S,
    threads: int = 1,
    max_upload_mb: float = 25.0,
) -> None:
    """Serve capture sessions over HTTP (JSON): create sessions, add captures, train in the
    background, propose reachable views, and uncertainty images of any pose. The API and its
    models are documented at http://HOST:PORT/docs.

    Each session is a folder under --root that `nerfaug train/propose/add ROOT/ID` also open.
    Stopped or killed, the service resumes every session, and its training, from its last save.

    Args:
        root: the folder holding the sessions (and datasets sessions may start from).
        host: the address to listen on; only this machine (127.0.0.1) unless a token is set.
        port: the port to listen on.
        token: a secret every request must send as `Authorization: Bearer TOKEN`; needed to
            listen beyond this machine.
        device: where the NeRFs train: auto (cuda when available, else cpu), cpu, cuda.
        checkpoint_every: save a training session after this many seconds (and when a job ends).
        threads: torch threads for training.
        max_upload_mb: the largest image file accepted, in MB.
    """
    token = token if token is not None else (os.environ.get(TOKEN_ENV) or None)
    _check_serve(root, host, port, token, checkpoint_every, threads, max_upload_mb)
    uvicorn, app = _service_app(root, device, token, checkpoint_every, threads, max_upload_mb)
    # The event loop answers /health and states while worker threads run torch: it gets the GIL
    # after 1 ms rather than 5, and the cyclic collector skips what was loaded at start (a full
    # pass over those ~375,000 objects took 0.4 s on the 2-core machine, every thread stopped).
    sys.setswitchinterval(0.001)
    gc.freeze()
    print(f"serving the sessions in {root} on http://{host}:{port} (API docs: /docs)", flush=True)
    uvicorn.run(app, host=host, port=port, log_level="warning")


def _check_serve(root: Path, host: str, port: int, token, checkpoint_every: float, threads: int, max_upload_mb: float):
    """`nerfaug serve`'s options, checked before anything is loaded."""
    if not is_loopback(host) and not token:
        raise SystemExit(
            f"--host {host}: listening beyond this machine needs a token (--token or the {TOKEN_ENV} "
            "environment variable), checked on every request"
        )
    for name, value, ok, rule in [
        ("port", port, 0 <= port <= 65535, "must be in 0-65535"),
        ("checkpoint-every", checkpoint_every, checkpoint_every > 0, "must be > 0 (seconds between saves)"),
        ("max-upload-mb", max_upload_mb, max_upload_mb > 0, "must be > 0"),
        ("threads", threads, threads >= 1, "must be >= 1"),
    ]:
        if not ok:
            raise ValueError(f"--{name} {value}: {rule}")
    if root.exists() and not root.is_dir():
        raise ValueError(f"--root {root}: not a folder")


def _service_app(root: Path, device: str, token, checkpoint_every: float, threads: int, max_upload_mb: float):
    """(uvicorn, the service's app over the sessions in `root`), torch set up for `threads`."""
    try:  # the service's packages are optional, and torch is not loaded for `--help`
        import uvicorn

        from nerfaug.device import configure_process, resolve_device
        from nerfaug.service.app import create_app
        from nerfaug.service.hub import SessionHub
    except ImportError as error:
        raise SystemExit(
            f"nerfaug serve needs the service's packages ({error.name} is missing): pip install 'nerfaug[serve]'"
        ) from None
    configure_process(threads=threads)
    _log_to_stderr()
    hub = SessionHub(root, device=str(resolve_device(device)), checkpoint_every=checkpoint_every)
    return uvicorn, create_app(hub, token=token, max_upload_mb=max_upload_mb)


def _log_to_stderr() -> None:
    """The service's own messages (a training job resumed after a restart, ...) as plain lines on stderr."""
    logger = logging.getLogger("nerfaug.service")
    if not logger.handlers:
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(logging.Formatter("%(message)s"))
        logger.addHandler(handler)
    logger.setLevel(logging.INFO)


def uncertainty(
    run: Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="RUN")],
    poses: Path,
    out: Path,
    width: Annotated[int | None, replaced_by("the training resolution", "INT")] = None,
    fisher: bool = True,
    fisher_width: int = 16,
    shared_scale: bool = True,
    device: Literal["auto", "cpu", "cuda"] = "auto",
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
        device: where the NeRF renders: auto (cuda when available, else cpu), cpu, cuda.
        threads: torch threads (one is the fastest on a machine that runs other work).
    """
    _check_uncertainty(run, out, width, fisher_width, threads)
    matrices, names = _poses_of(poses)
    session = _session_for(run, device, threads)
    maps = session.uncertainty_maps(matrices, width, fisher, fisher_width, progress=True, names=names)
    _write_uncertainty(out, names, maps, shared_scale)


def _check_uncertainty(run: Path, out: Path, width: int | None, fisher_width: int, threads: int) -> None:
    """`nerfaug uncertainty`'s options, checked before anything is read."""
    for name, value in (("width", width), ("fisher-width", fisher_width), ("threads", threads)):
        if value is not None and value < 1:
            raise ValueError(f"--{name} {value}: must be >= 1")
    if not owned.is_empty(out) and not owned.marked(out, UNCERTAINTY_KIND):
        raise FolderRefused(f"{out}: not empty and not written by `nerfaug uncertainty`; choose a new folder for --out")
    if owned.overlaps(out, run):
        raise FolderRefused(f"{out}: lies inside or holds the session {run}; choose a folder outside it")


def _poses_of(path: Path):
    from nerfaug.capture.proposal import read_poses  # torch: not loaded for `--help`

    return read_poses(path)


def _session_for(run: Path, device: str, threads: int):
    """The session in `run` on `device`, torch on `threads` threads."""
    from nerfaug.capture.session import CaptureSession  # torch: not loaded for `--help`
    from nerfaug.device import configure_process, resolve_device

    configure_process(threads=threads)
    return CaptureSession.open(run, device=str(resolve_device(device)))


def _write_uncertainty(out: Path, names: list[str], maps: list, shared_scale: bool) -> None:
    """Each view's figure and arrays into `out`, one line each."""
    from nerfaug.capture.uncertainty_images import colour_scales, write_maps  # torch, matplotlib: as above

    owned.mark(out, UNCERTAINTY_KIND)
    scales = colour_scales(maps) if shared_scale else None
    for name, view in zip(names, maps):
        write_maps(view, out, name, scales)
        print(f"{name}: mean entropy {view.entropy.mean():.3f} bits -> {out / (name + '.png')}")
    if scales is not None and len(maps) > 1:
        print(f"the {len(maps)} figures share their colour scales (--no-shared-scale: each its own)")


COMMANDS: dict = {"serve": serve, "uncertainty": uncertainty}
