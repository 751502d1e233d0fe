"""The CLI command that shows a capture session in the browser.

    nerfaug view RUN --port 8080                    cameras, candidates by score, proposals, live render

Its work, which loads torch and viser (an optional package: `pip install 'nerfaug[viewer]'`), is
`nerfaug.cli.view_work`, imported when the command runs, so that `--help` answers at once.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import tyro

from nerfaug.cli.serve import is_loopback


def view(
    run: Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="RUN")],
    host: str = "127.0.0.1",
    port: int = 8080,
    live: bool = True,
) -> None:
    """Show a capture session in the browser: the training cameras with their images, the candidate
    views coloured by the last proposal's score, the proposed views by rank, the held-out views,
    the hemisphere and the NeRF's box, with a live render of the NeRF at your camera (small while
    it moves, sharper when it rests). It follows the session: a training, a proposal or an addition
    shows up without a restart. It only reads the run folder, and renders on one thread at a low
    priority, so a training beside it keeps the machine.

    Args:
        run: the session's run folder (also a session of `nerfaug serve --root`).
        host: the address to listen on; only this machine (127.0.0.1) unless another is given.
        port: the port to listen on (the next free one when it is taken; the line at start names it).
        live: render the NeRF at the browser's camera.
    """
    if not 0 <= port <= 65535:
        raise SystemExit(f"--port {port}: must be in 0-65535")
    from nerfaug.cli import view_work  # torch and viser: here, so that `nerfaug view --help` loads neither

    if not is_loopback(host):
        print(f"warning: --host {host}: the viewer is open to every machine that reaches this one (no token)")
    view_work.view(run, host, port, live)
