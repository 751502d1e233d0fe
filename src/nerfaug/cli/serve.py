"""The CLI command for capturing with a robot: the HTTP service over capture sessions.

    nerfaug serve --root SESSIONS                   the HTTP JSON service (API docs at /docs)

Its work, which loads torch (and FastAPI, an optional package: `pip install 'nerfaug[serve]'`), is
`nerfaug.cli.serve_work`, imported when the command runs, so that `--help` answers at once.
"""

from __future__ import annotations

import gc
import ipaddress
import os
import sys
from pathlib import Path
from typing import Annotated

import tyro

from nerfaug.capture.requests import (
    CHECKPOINT_EVERY_S,
    check_checkpoint_every,
    check_threads,
    replaced_by,
)
from nerfaug.cli.option_names import as_options, engine_refusal
from nerfaug.device_choice import Device
from nerfaug.nerf.config import PRESETS
from nerfaug.nerf.engine import Engine

TOKEN_ENV = "NERFAUG_TOKEN"


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
    device: Device = "auto",
    checkpoint_every: float = CHECKPOINT_EVERY_S,
    threads: int = 1,
    max_upload_mb: float = 25.0,
    engine_settings: tyro.conf.Suppress[dict | None] = None,
) -> None:
    """Serve capture sessions over HTTP (JSON): create sessions, add captures, train in the
    background, propose reachable views, and uncertainty images of any pose. The API and its
    models are documented at http://HOST:PORT/docs.

    Each session is a folder under --root that `nerfaug train/propose/add ROOT/ID` also open.
    Stopped or killed, the service resumes every session, and its training, from its last save.

    Any setting of the engine is an option too, over the engine's own value:
    --engine.GROUP.SETTING VALUE (e.g. --engine.field.hidden-dim 32); `nerfaug engines` lists them.

    Args:
        root: the folder holding the sessions (and datasets sessions may start from).
        host: the address to listen on; only this machine (127.0.0.1) unless a token is set.
        port: the port to listen on.
        token: a secret every request must send as `Authorization: Bearer TOKEN`; needed to
            listen beyond this machine.
        device: where the NeRFs train.
        checkpoint_every: save a training session after this many seconds (and when a job ends).
        threads: torch threads for training.
        max_upload_mb: the largest image file accepted, in MB.
        engine_settings: the --engine.GROUP.SETTING given (nested by component; read apart from
            these options), over those of the engine each new session asks for: its engine is then
            the variant that changes them.
    """
    token = token if token is not None else (os.environ.get(TOKEN_ENV) or None)
    _check_serve(root, host, port, token, checkpoint_every, threads, max_upload_mb)
    engine = engine_settings or {}
    _check_engine_settings(engine)
    from nerfaug.cli import serve_work  # torch: here, so that `nerfaug serve --help` loads none

    uvicorn, app = serve_work.service_app(root, device, token, checkpoint_every, threads, max_upload_mb, engine)
    # The event loop answers /health and states while worker threads run torch: it gets the GIL
    # after 1 ms rather than 5, and the cyclic collector skips what was loaded at start (a full
    # pass over those ~375,000 objects took 0.4 s on the 2-core machine, every thread stopped).
    sys.setswitchinterval(0.001)
    gc.freeze()
    print(f"serving the sessions in {root} on http://{host}:{port} (API docs: /docs)", flush=True)
    uvicorn.run(app, host=host, port=port, log_level="warning")


def _check_engine_settings(settings: dict) -> None:
    """The --engine.GROUP.SETTING given, tried on every engine before the service starts: refused
    when no engine takes them, and the engines that refuse them named (their sessions will be
    refused, 422 naming "engine")."""
    if not settings:
        return
    refusals = {}
    for engine in PRESETS:
        try:
            Engine.of(engine, settings)
        except ValueError as error:
            refusals[engine] = engine_refusal(error)
    if len(refusals) == len(PRESETS):
        raise SystemExit(next(iter(refusals.values())))
    if refusals:
        names = ", ".join(refusals)
        print(
            f"warning: a session asking for the engine {names} will be refused: {next(iter(refusals.values()))}",
            file=sys.stderr,
        )


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
