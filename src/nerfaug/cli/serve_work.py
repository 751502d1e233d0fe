"""The work of `nerfaug serve`, whose options are in `nerfaug.cli.serve`: the service's app over a
folder of sessions. This module loads torch: `nerfaug.cli.serve` imports it only when the command
runs.
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path

from nerfaug.capture import pool
from nerfaug.device import configure_process, resolve_device


def service_app(
    root: Path, device: str, token, checkpoint_every: float, threads: int, max_upload_mb: float, engine_settings=None
):
    """(uvicorn, the service's app over the sessions in `root`), torch set up for `threads`;
    `engine_settings` (nested by component) change the engine of every session it creates."""
    try:  # the service's packages are optional (FastAPI, imported by the service's modules)
        import uvicorn

        from nerfaug.service import app, hub
    except ImportError as error:
        raise SystemExit(
            f"nerfaug serve needs the service's packages ({error.name} is missing): pip install 'nerfaug[serve]'"
        ) from None
    configure_process(threads=threads)
    _log_to_stderr(app)
    sessions = hub.SessionHub(
        root, device=str(resolve_device(device)), checkpoint_every=checkpoint_every, engine_settings=engine_settings
    )
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
