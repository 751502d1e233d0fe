"""The work of `nerfaug view` (`nerfaug.cli.view`): the viewer served until Ctrl-C."""

from __future__ import annotations

import contextlib
import os
import time
from pathlib import Path

from nerfaug.device import configure_process

# The viewer yields the cores to a training beside it: its renders run at this niceness, on one thread.
NICENESS = 10
MISSING = "the viewer needs the optional extra: pip install 'nerfaug[viewer]'"


def view(run: Path, host: str, port: int, live: bool) -> None:
    try:
        from nerfaug.viewer.app import Viewer
    except ImportError as error:
        if error.name is not None and error.name.split(".")[0] in ("viser", "websockets", "msgspec"):
            raise SystemExit(f"nerfaug view: {MISSING} ({error.name} is missing)") from None
        raise
    configure_process(threads=1)
    with contextlib.suppress(OSError, AttributeError):  # AttributeError: no os.nice (Windows)
        os.nice(NICENESS)
    viewer = Viewer(run, host=host, port=port, live=live)
    try:
        print(f"viewing the session {run} on {viewer.url} (Ctrl-C to stop)", flush=True)
        while True:
            time.sleep(1.0)
    finally:
        viewer.stop()
