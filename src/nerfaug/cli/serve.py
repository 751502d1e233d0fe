"""CLI commands for capturing with a robot: the HTTP service over capture sessions, and
uncertainty images of any view of a session.

    nerfaug serve --root SESSIONS                   the HTTP JSON service (API docs at /docs)
    nerfaug uncertainty RUN --poses POSES.json --out DIR

Their work, which loads torch (and FastAPI, an optional package: `pip install 'nerfaug[serve]'`),
is `nerfaug.cli.serve_work`, imported when a command runs, so that `--help` answers at once.
"""

from __future__ import annotations

import gc
import ipaddress
import os
import sys
from pathlib import Path
from typing import Annotated, Literal

import tyro

from nerfaug import owned
from nerfaug.capture.requests import (
    CHECKPOINT_EVERY_S,
    check_checkpoint_every,
    check_image_widths,
    check_threads,
    replaced_by,
)
from nerfaug.cli.option_names import as_options
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
    from nerfaug.cli import serve_work  # torch: here, so that `nerfaug serve --help` loads none

    uvicorn, app = serve_work.service_app(root, device, token, checkpoint_every, threads, max_upload_mb)
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
        ("max-upload-mb", max_upload_mb, max_upload_mb > 0, "must be > 0"),
    ]:
        if not ok:
            raise ValueError(f"--{name} {value}: {rule}")
    with as_options():
        check_checkpoint_every(checkpoint_every)
        check_threads(threads)
    if root.exists() and not root.is_dir():
        raise ValueError(f"--root {root}: not a folder")


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
    from nerfaug.cli import serve_work  # torch, matplotlib: here, so that `--help` loads neither

    serve_work.uncertainty(
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
