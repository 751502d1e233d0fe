"""The work of `nerfaug serve` and `nerfaug uncertainty`, whose options are in `nerfaug.cli.serve`:
the service's app over a folder of sessions, and a session's uncertainty images written. This module
loads torch: `nerfaug.cli.serve` imports it only when a command runs.
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path

from nerfaug import owned
from nerfaug.capture import pool
from nerfaug.capture.proposal import read_poses
from nerfaug.capture.session import CaptureSession
from nerfaug.capture.uncertainty_images import colour_scales, write_maps
from nerfaug.device import configure_process, resolve_device


def service_app(root: Path, device: str, token, checkpoint_every: float, threads: int, max_upload_mb: float):
    """(uvicorn, the service's app over the sessions in `root`), torch set up for `threads`."""
    try:  # the service's packages are optional (FastAPI, imported by the service's modules)
        import uvicorn

        from nerfaug.service import app, hub
    except ImportError as error:
        raise SystemExit(
            f"nerfaug serve needs the service's packages ({error.name} is missing): pip install 'nerfaug[serve]'"
        ) from None
    configure_process(threads=threads)
    _log_to_stderr(app)
    sessions = hub.SessionHub(root, device=str(resolve_device(device)), checkpoint_every=checkpoint_every)
    return uvicorn, app.create_app(sessions, token=token, max_upload_mb=max_upload_mb)


def _log_to_stderr(app_module) -> None:
    """The service's own messages (a training job resumed after a restart, ...) and its request log
    (`service.app.RequestLog`: one line per request) as plain lines on stderr."""
    for name in (pool.__name__, app_module.__name__):
        logger = logging.getLogger(name)
        if not logger.handlers:
            handler = logging.StreamHandler(sys.stderr)
            handler.setFormatter(logging.Formatter("%(message)s"))
            logger.addHandler(handler)
        logger.setLevel(logging.INFO)


def uncertainty(run: Path, poses: Path, out: Path, kind: str, device: str, threads: int, sizes: tuple, shared: bool):
    """`nerfaug uncertainty` (`nerfaug.cli.serve.uncertainty`), its options checked: the maps of
    each pose in the poses JSON `poses`, at `sizes` (width, fisher, fisher_width), of the session
    in `run` (torch on `threads` threads), written into `out`, marked as a folder of the `kind`."""
    matrices, names = read_poses(poses)
    configure_process(threads=threads)
    session = CaptureSession.open(run, device=str(resolve_device(device)))
    maps = session.uncertainty_maps(matrices, *sizes, progress=True, names=names)
    owned.mark(out, kind)
    _write_uncertainty(out, names, maps, shared)


def _write_uncertainty(out: Path, names: list[str], maps: list, shared_scale: bool) -> None:
    """Each view's figure and arrays into `out`, one line each."""
    scales = colour_scales(maps) if shared_scale else None
    for name, view in zip(names, maps):
        write_maps(view, out, name, scales)
        print(f"{name}: mean entropy {view.entropy.mean():.3f} bits -> {out / (name + '.png')}")
    if scales is not None and len(maps) > 1:
        print(f"the {len(maps)} figures share their colour scales (--no-shared-scale: each its own)")
