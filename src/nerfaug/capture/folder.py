"""`SessionFolder`: a capture session's run folder read without its model (its state, session.json,
and its grown dataset): what reading, reporting (`summary`) and exporting a session need, and the
base `CaptureSession` adds the model to. The layout of the folder is drawn in
`nerfaug.capture.session`."""

from __future__ import annotations

from pathlib import Path

import torch

from nerfaug import runfiles
from nerfaug.cameras import Cameras
from nerfaug.capture import export, integrity
from nerfaug.capture.dataset import HELD_OUT_KEY, engine_views
from nerfaug.capture.evaluate import TestViews, choose_test_views, load_held_out, narrowed
from nerfaug.capture.requests import Intrinsics, Split, validated
from nerfaug.capture.runfolder import CHECKPOINT_FILE, DATASET_DIR, DATASET_SPLIT, SESSION_FILE
from nerfaug.capture.state import AdditionRecord, ProposalRecord, SessionError, SessionState, SessionSummary
from nerfaug.containment import inside
from nerfaug.data.formats import EXCHANGE_FORMAT, FORMATS, get_format
from nerfaug.data.interface import DatasetSplit
from nerfaug.data.views import Views
from nerfaug.data.world_frame import Hemisphere


def camera_of(k: Intrinsics, width: int | None = None, height: int | None = None) -> Cameras:
    """One camera with intrinsics `k` at the identity pose (full resolution unless a size is given)."""
    camera = Cameras(torch.eye(4), k.fx, k.fy, k.cx, k.cy, k.width, k.height)
    return camera if width is None else camera.resized(width, height)


class SessionFolder:
    """A session's run folder without its model: its state (session.json) and its grown dataset;
    enough to read the state, report it (`summary`) or `export`. `CaptureSession` adds the model.
    """

    def __init__(self, run_dir: Path, state: SessionState):
        self.run_dir = Path(run_dir)
        self.state = state

    @classmethod
    def open(cls, run_dir: str | Path) -> SessionFolder:
        """The run folder's state and dataset, its captures checked against their digests.

        Raises:
            SessionError: naming the missing or inconsistent file, or the field of session.json
                that is missing, malformed or points outside the run folder.
        """
        folder = SessionFolder(Path(run_dir), SessionState.read(Path(run_dir)))
        integrity.check_captures(folder.dataset_split(), folder.frames(), folder.state.integrity.captures)
        return folder

    @property
    def seed(self) -> int:
        return self.state.seed

    @property
    def hemisphere(self) -> Hemisphere:
        return self.state.hemisphere

    @property
    def dataset_dir(self) -> Path:
        """The dataset copy's folder, resolved; `PathRefused` if it leads outside the run folder."""
        return runfiles.path_in(self.run_dir, DATASET_DIR)

    @property
    def proposals(self) -> list[ProposalRecord]:
        """The proposal history (one record per `propose` call), as stored in session.json."""
        return self.state.proposals

    @property
    def additions(self) -> list[AdditionRecord]:
        """The additions (one record per `add_views` call), as stored in session.json."""
        return self.state.additions

    @property
    def cameras(self) -> Cameras:
        """The world-frame cameras of every view in the dataset, at full resolution."""
        return self.dataset().cameras

    def dataset(self) -> Views:
        """The grown dataset, world frame, full resolution (images loaded on access)."""
        return self.dataset_split().load(lazy=True, background=tuple(self.state.background))

    def template(self, width: int | None = None, height: int | None = None) -> Cameras:
        """One camera with the session's intrinsics at the identity pose (full resolution unless a
        size is given)."""
        return camera_of(self.state.intrinsics, width, height)

    def dataset_split(self) -> DatasetSplit:
        """The grown dataset's split in its format; `PathRefused` if its listing leads outside the run folder."""
        dataset = DatasetSplit(self.dataset_dir, FORMATS[self.state.dataset.format], DATASET_SPLIT)
        shown = dataset.listing.relative_to(self.dataset_dir.parent).as_posix()
        inside(
            self.run_dir,
            dataset.listing,
            "the dataset's listing",
            listed_in=runfiles.shown(self.run_dir, SESSION_FILE),
            value=shown,
        )
        return dataset

    def frames(self) -> list:
        """The frames listed by the dataset (DatasetError unless a list)."""
        return self.dataset_split().frames()

    def engine_views(self, start: int) -> Views:
        """Dataset frames `start:` loaded as the trainer sees them: downscaled, engine frame."""
        state = self.state
        return engine_views(self.dataset_split(), start, state.downscale, state.background, self.hemisphere)

    def checkpoint(self) -> bytes:
        """The run folder's checkpoint (its bytes, read once: what is checked is what is loaded),
        checked against the digest session.json records.

        Raises:
            SessionError: it is missing, or not this session's.
            PathRefused: it leads outside the run folder.
        """
        path = runfiles.shown(self.run_dir, CHECKPOINT_FILE)
        if not runfiles.exists(self.run_dir, CHECKPOINT_FILE):
            raise SessionError(f"{path}: checkpoint not found; the run folder is incomplete")
        try:
            data = runfiles.read_bytes(self.run_dir, CHECKPOINT_FILE)
        except OSError as error:
            raise SessionError(f"{path}: cannot read the checkpoint ({error.strerror or error})") from None
        integrity.check_checkpoint(path, data, self.state.integrity)
        return data

    def summary(self) -> SessionSummary:
        """What the session's files say of it (no losses: they are in the checkpoint)."""
        return self._summary(self.state.step, [str(f["file_path"]) for f in self.frames()], [])

    def _summary(self, step: int, names: list[str], losses: list[dict]) -> SessionSummary:
        state = self.state
        return SessionSummary(
            id=self.run_dir.name,
            step=step,
            views=len(names),
            names=names,
            last_losses=losses,
            proposals=len(state.proposals),
            additions=len(state.additions),
            hemisphere=state.hemisphere.to_dict(),
            intrinsics=state.intrinsics,
        )

    def default_test_split(self) -> str:
        """The split `evaluate` scores when none is named: the one a sparse start kept views apart
        from (its views kept apart are then scored), else "test"."""
        start = self.state.start
        return self.state.source.split if start and start.get(HELD_OUT_KEY) else "test"

    def test_views(
        self, data: str | Path, split: str | None = None, max_views: int | None = None
    ) -> tuple[Views, TestViews]:
        """The views of `split` (default: `default_test_split`) of the dataset folder `data` (same
        scene and world frame) the session is scored on (`choose_test_views`: a sparse start's
        views kept apart, where it kept some) at the training resolution, over the session's
        background; and which they are, for the user."""
        split = validated(Split, self.default_test_split() if split is None else split, "split")
        views = load_held_out(data, split, self.state.downscale, self.state.background)
        chosen = choose_test_views(self.state.start, self.state.source.split, Path(data), split, views.names)
        return narrowed(views, chosen.names, max_views), chosen

    def held_out(self, data: str | Path, split: str | None = None, max_views: int | None = None) -> Views:
        """What `evaluate` scores: `test_views`' views."""
        return self.test_views(data, split, max_views)[0]

    def export(self, out: str | Path, format: str = EXCHANGE_FORMAT, source_splits: bool = True) -> Path:
        """Write the grown dataset to `out` in `format` (a name in `nerfaug.data.FORMATS`) so other
        tools open it.

        "nerfstudio": `transforms.json` (OPENCV camera model, intrinsics global or per frame) and
        `images/`, for nerfstudio (`ns-train nerfacto --data OUT`) and instant-ngp.
        "blender": `transforms_train.json` and `train/*.png` (NeRF-synthetic), plus the source's
        val and test splits when it has them (nerfstudio's blender parser needs a val split).
        Images are copied byte for byte (never decoded and re-encoded), except non-PNG images
        in a format that reads PNG only (Blender), which become lossless PNGs.

        `out` must be new, empty, or an earlier export (nerfaug's marker): nothing else is written over.

        Returns the transforms JSON path (of the train split for "blender").

        Raises:
            FolderRefused: `out` holds files nerfaug did not write, or overlaps the run folder.
            ValueError: an unknown format, or one that cannot describe the session's cameras.
        """
        source = self.state.source
        return export.export(
            self.dataset_split(),
            out,
            get_format(format),
            self.run_dir,
            Path(source.data_dir),
            source.split,
            source_splits,
        )
