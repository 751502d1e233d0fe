"""`Viewer`: a capture session in the browser, served by viser: the scene (`nerfaug.viewer.scene`),
a panel (the session's step, views and last evaluation; the colour bar of the candidates' score;
each proposal to pick, with its map and the images found beside it), and a live render of the
session's NeRF behind the scene at each browser's camera (`nerfaug.viewer.render`).

It follows the session: every `poll_s` it looks at the modification times of the session's files
(`snapshot.changed_key`) and redraws what changed; a new checkpoint is loaded for the live render.
It writes nothing into the run folder.
"""

from __future__ import annotations

import contextlib
import io
import threading
import time
from pathlib import Path

import numpy as np
import viser
import viser.transforms as vtf

from nerfaug.errors import NerfaugError
from nerfaug.viewer import scene
from nerfaug.viewer.render import (
    MOVING_BUDGET_S,
    MOVING_WIDTH,
    RESTING_BUDGET_S,
    RESTING_WIDTH,
    LiveModel,
    width_for,
)
from nerfaug.viewer.snapshot import Snapshot, changed_key, read_snapshot, thumbnail

POLL_S = 1.0
REST_S = 0.3  # the camera still for this long: the frame is rendered again, sharper
IDLE_S = 0.05  # how often a browser's camera is looked at
PANEL_IMAGE_WIDTH = 240
STOP_S = 30.0  # at most this long to wait at the end for a checkpoint being loaded


def proposal_label(proposal) -> str:
    return f"#{proposal.number}: {len(proposal.names)} views, {proposal.method}, step {proposal.step}"


class Viewer:
    """The viewer of the session in `run_dir`, serving at `host:port` (0: any free port) once
    made; `stop()` ends it. `live`: render the NeRF at each browser's camera."""

    def __init__(self, run_dir: Path, host: str = "127.0.0.1", port: int = 8080, live: bool = True,
                 poll_s: float = POLL_S) -> None:  # fmt: skip
        self.run_dir = Path(run_dir)
        self.poll_s = poll_s
        self.key = changed_key(self.run_dir)
        self.snapshot: Snapshot = read_snapshot(self.run_dir)
        self.picked = self.snapshot.proposals[-1].number if self.snapshot.proposals else None
        self.redraws = 0
        self._stop = threading.Event()
        self._redraw_lock = threading.Lock()
        with contextlib.redirect_stdout(io.StringIO()):  # viser's banner: `nerfaug view` prints its own line
            self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.read_error = ""
        self.live = None
        if live:
            self.live = LiveModel(self.run_dir, self.snapshot.hemisphere, self.snapshot.background)
        position, look_at = scene.first_view(self.snapshot)
        self.server.initial_camera.position = tuple(position)
        self.server.initial_camera.look_at = tuple(look_at)
        self._panel()
        self.redraw()
        self.server.on_client_connect(self._connected)
        self._threads = [threading.Thread(target=self._follow, name="viewer-follow", daemon=True)]
        for thread in self._threads:
            thread.start()

    @property
    def url(self) -> str:
        host = self.server.get_host()
        return f"http://{'127.0.0.1' if host in ('0.0.0.0', '') else host}:{self.server.get_port()}/"

    def stop(self) -> None:
        self._stop.set()
        with contextlib.redirect_stdout(io.StringIO()):
            self.server.stop()
        # A checkpoint being loaded finishes first: torch aborts the process when it exits under a running load.
        for thread in self._threads:
            thread.join(timeout=STOP_S)

    # ---- the panel -------------------------------------------------------------------------------------------

    def _panel(self) -> None:
        gui = self.server.gui
        gui.configure_theme(control_width="large")
        self.status = gui.add_markdown("")
        with gui.add_folder("Candidates"):
            self.score_label = gui.add_markdown("")
            self.score_bar = gui.add_image(scene.colour_bar(), format="png")
            self.score_range = gui.add_markdown("")
        with gui.add_folder("Proposals"):
            self.proposal_menu = gui.add_dropdown("proposal", ["(none yet)"])
            self.proposal_menu.on_update(lambda _: self._pick(self.proposal_menu.value))
            self.proposal_box = gui.add_folder("picked proposal")
        with gui.add_folder("Live render"):
            self.live_box = gui.add_checkbox("render the NeRF", self.live is not None, disabled=self.live is None)
            self.live_box.on_update(lambda _: self._clear_backgrounds())
            self.live_note = gui.add_markdown("loading the checkpoint" if self.live is not None else "off")
        self._proposal_images: list = []
        self._setting_menu = False

    def _update_panel(self) -> None:
        s = self.snapshot
        lines = [f"**{s.run_dir.name}**: step {s.step}, {s.views} views, engine `{s.engine}`"]
        lines.append(f"hemisphere: {s.hemisphere}")
        if s.evaluation is not None:
            mean = s.evaluation["mean"]
            scores = ", ".join(f"{k} {v:.3f}" for k, v in mean.items() if isinstance(v, int | float))
            lines.append(f"last evaluation (step {s.evaluation['step']}, {s.evaluation['split']}): {scores}")
        else:
            lines.append("last evaluation: none found (`nerfaug eval RUN ... --out RUN/eval.json`)")
        lines.append(f"{len(s.held_out)} held-out views (grey), {len(s.candidates.positions)} candidates")
        if self.read_error:
            lines.append(f"**the session could not be read just now** (the view above is older): {self.read_error}")
        self.status.content = "\n\n".join(lines)
        c = s.candidates
        self.score_label.content = f"colour: **{c.label}**"
        if c.scores is not None and len(c.scores):
            self.score_range.content = f"low {c.scores.min():.4g} (dark) to high {c.scores.max():.4g} (yellow)"
        else:
            self.score_range.content = "grey: not scored yet"
        labels = [proposal_label(p) for p in s.proposals] or ["(none yet)"]
        picked = next((proposal_label(p) for p in s.proposals if p.number == self.picked), labels[-1])
        # viser calls the menu's on_update from these assignments, in this thread, inside the redraw:
        # `_pick` ignores them (a redraw from there would wait on the redraw's own lock).
        self._setting_menu = True
        try:
            self.proposal_menu.options = labels
            if self.proposal_menu.value != picked:
                self.proposal_menu.value = picked
        finally:
            self._setting_menu = False
        self._show_proposal()

    def _pick(self, label: str) -> None:
        if self._setting_menu:
            return
        number = next((p.number for p in self.snapshot.proposals if proposal_label(p) == label), None)
        if number is not None and number != self.picked:
            self.picked = number
            self.redraw()

    def _show_proposal(self) -> None:
        for handle in self._proposal_images:
            handle.remove()
        self._proposal_images = []
        proposal = next((p for p in self.snapshot.proposals if p.number == self.picked), None)
        if proposal is None:
            return
        with self.proposal_box:
            if proposal.refused:
                note = f"its folder was not read: {proposal.refused}"
                self._proposal_images.append(self.server.gui.add_markdown(note))
                return
            if proposal.map is not None:
                image = thumbnail(proposal.map, (1, 1, 1), PANEL_IMAGE_WIDTH)
                if image is not None:
                    self._proposal_images.append(self.server.gui.add_image(image, label="hemisphere map"))
            for paths in proposal.images.values():
                for path in paths[:2]:  # its render and uncertainty figure; the arrays are not images
                    image = thumbnail(path, (1, 1, 1), PANEL_IMAGE_WIDTH)
                    if image is not None:
                        self._proposal_images.append(self.server.gui.add_image(image, label=path.name))
            if not proposal.images:
                self._proposal_images.append(
                    self.server.gui.add_markdown(
                        "no renders or uncertainty images beside this proposal (`nerfaug uncertainty RUN "
                        "--poses RUN/proposals/proposal_NNN.json --out RUN/proposals/proposal_NNN`)"
                    )
                )

    # ---- following the session -------------------------------------------------------------------------------

    def redraw(self) -> None:
        with self._redraw_lock, self.server.atomic():
            scene.draw(self.server, self.snapshot, self.picked)
            self._update_panel()
            self.redraws += 1

    def _follow(self) -> None:
        if self.live is not None:
            self._load()
        while not self._stop.wait(self.poll_s):
            key = changed_key(self.run_dir)
            if key == self.key:
                continue
            try:
                snapshot = read_snapshot(self.run_dir)
            except (NerfaugError, OSError, ValueError) as error:
                # Caught between two writes, or being repaired: looked at again next time, and said
                # in the panel meanwhile (the last good snapshot stays drawn).
                self.read_error = f"{type(error).__name__}: {error}"
                with self._redraw_lock:
                    self._update_panel()
                continue
            self.read_error = ""
            self.key = key
            known = {p.number for p in self.snapshot.proposals}
            self.snapshot = snapshot
            if any(p.number not in known for p in snapshot.proposals):
                self.picked = snapshot.proposals[-1].number  # a new proposal: shown at once
            self.redraw()
            if self.live is not None:
                self.live.set_hemisphere(snapshot.hemisphere)
                self._load()

    def _load(self) -> None:
        if self.live.refresh() and not self._stop.is_set():
            self.live_note.content = f"the NeRF at step {self.live.step}"

    # ---- the live render -------------------------------------------------------------------------------------

    def _clear_backgrounds(self) -> None:
        if not self.live_box.value:
            for client in self.server.get_clients().values():
                client.scene.set_background_image(None)

    def _connected(self, client: viser.ClientHandle) -> None:
        if self.live is not None:
            threading.Thread(target=self._render_loop, args=(client,), name="viewer-render", daemon=True).start()

    def _render_loop(self, client: viser.ClientHandle) -> None:
        """Render for one browser: small while its camera moves, sharper once it rests, again
        when a new checkpoint is loaded; each frame's size within its time budget."""
        seen, moved_at, sharp_for = None, time.monotonic(), None
        while not self._stop.is_set() and client.client_id in self.server.get_clients():
            camera = client.camera
            stamp = (camera.update_timestamp, self.live.loaded_key, self.live_box.value)
            if stamp != seen:
                seen, moved_at, sharp_for = stamp, time.monotonic(), None
                target, budget = MOVING_WIDTH, MOVING_BUDGET_S
            elif sharp_for != stamp and time.monotonic() - moved_at > REST_S:
                sharp_for, target, budget = stamp, RESTING_WIDTH, RESTING_BUDGET_S
            else:
                time.sleep(IDLE_S)
                continue
            if not self.live_box.value:
                continue
            pose = np.eye(4)
            pose[:3, :3] = vtf.SO3(np.asarray(camera.wxyz)).as_matrix()
            pose[:3, 3] = camera.position
            aspect = float(camera.aspect) if camera.aspect > 0 else 1.0
            width = width_for(target, aspect, budget, self.live.seconds_per_pixel)
            start = time.perf_counter()
            image = self.live.render(pose, float(camera.fov), aspect, width)
            if image is None:
                continue
            client.scene.set_background_image(image, format="jpeg", jpeg_quality=90)
            took = time.perf_counter() - start
            self.live_note.content = (
                f"the NeRF at step {self.live.step}: {image.shape[1]}x{image.shape[0]} px in {took * 1000:.0f} ms"
            )
