"""`CaptureSession`: train a NeRF on the views you have, ask which views to capture next, add the
images you captured there (a robot, a phone, a simulator), and go on training.

A session lives in a run folder:

    run/
      .nerfaug              marker: nerfaug made this folder (nothing is removed from a folder without it)
      .lock                 who changes the session now (`nerfaug.capture.lock`; the commands and the service)
      session.json          state (`SessionState`): step, seed, engine, intrinsics, hemisphere, proposals, additions
      checkpoint.pt         the trainer (`Trainer.save_checkpoint`): model, optimiser, RNG, views
      dataset/              the dataset as it has grown, as the train split of a registered format
                              (`nerfaug.data.FORMATS`): Blender (`transforms_train.json` + `train/*.png`)
                              when one camera_angle_x describes its cameras, else the source's own
                              (nerfstudio: `transforms.json` + `images/*`)
      proposals/            proposal_000.json (poses + every candidate's score), proposal_000.png (map)

Poses given to and returned by a session are in the dataset's world frame; the NeRF is trained in
the engine frame of the session's hemisphere (`nerfaug.data.frame`).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from pathlib import Path

import torch
from torch import Tensor

from nerfaug import owned
from nerfaug.cameras import Cameras
from nerfaug.capture import add, choose, export, integrity
from nerfaug.capture.dataset import duplicate_frames, engine_views
from nerfaug.capture.evaluate import evaluate_model, load_held_out
from nerfaug.capture.model import SessionModel
from nerfaug.capture.proposal import Proposal
from nerfaug.capture.requests import check_radius, check_seed, check_split, check_steps
from nerfaug.capture.runfolder import check_new_run
from nerfaug.capture.state import (
    CHECKPOINT_FILE,
    DATASET_DIR,
    DATASET_KIND,
    DATASET_SPLIT,
    PROPOSALS_DIR,
    RUN_KIND,
    SESSION_FILE,
    AdditionRecord,
    DatasetInfo,
    DuplicateViews,
    Intrinsics,
    ProposalRecord,
    SessionError,
    SessionState,
    SourceInfo,
    now,
)
from nerfaug.capture.uncertainty_images import ViewMaps, view_maps
from nerfaug.data.format import DatasetSplit
from nerfaug.data.formats import EXCHANGE_FORMAT, FORMATS, find_split, get_format, plainest_format
from nerfaug.data.frame import Hemisphere, estimate_hemisphere
from nerfaug.data.views import Views
from nerfaug.evaluation import EvaluationResult
from nerfaug.jsonio import atomic_write_bytes, atomic_write_json


class CaptureSession:
    """Active capture over a dataset folder and a run folder; see the module docstring.

    Make one with `create` (from a dataset) or `open` (a run folder), not the constructor.
    Changes to the model and the proposal history are kept in memory until `save()`; `add_views`
    writes the grown dataset at once (it is the data), and `open` re-reads views the checkpoint
    has not seen yet, so nothing captured is ever lost.

    Example:
        >>> session = CaptureSession.create("data/lego", "runs/lego", split="initial")  # doctest: +SKIP
        >>> session.train(1000)                                      # doctest: +SKIP
        >>> proposal = session.propose(6)                            # doctest: +SKIP
        >>> proposal.write("poses.json")                             # doctest: +SKIP
        >>> session.add_views("captures/", "poses.json")             # doctest: +SKIP
        >>> session.train(1000); session.save()                      # doctest: +SKIP
    """

    def __init__(self, run_dir: Path, trainer, state: SessionState):
        self.run_dir = Path(run_dir)
        self.trainer = trainer
        self.state = state
        self._saved: tuple[int, int] | None = None  # (step, views) of the checkpoint on disk

    # -- creation and persistence --

    @classmethod
    def create(
        cls,
        data_dir: str | Path,
        run_dir: str | Path,
        preset: str = "cpu",
        seed: int = 0,
        split: str = "train",
        *,
        config=None,
        centre=None,
        radius: float | None = None,
        up=(0.0, 0.0, 1.0),
        downscale: int = 1,
        background=(1.0, 1.0, 1.0),
        device="cpu",
        progress: bool = False,
    ) -> CaptureSession:
        """Start a session: copy `split` of the dataset into `run_dir/dataset`, build the NeRF,
        save. Nothing is trained yet (call `train`).

        Args:
            data_dir: a dataset folder in a registered format (`nerfaug.data.FORMATS`: Blender's
                `transforms_{split}.json`, nerfstudio's `transforms.json`): the views captured so far.
            run_dir: the run folder to create (must not hold a session already).
            preset: NeRF engine preset ("cpu", "paper", "test"); ignored if `config` is given.
            seed: seeds the model's initialisation, its training and every proposal.
            split: the split holding the captured views ("initial" for built-in scenes).
            config: a `NerfConfig` to use instead of the preset.
            centre, radius: the hemisphere; None estimates them from the cameras (centre: the
                point closest to all optical axes; radius: the mean camera distance to it).
            up: the hemisphere's pole, world space; "estimate" for the mean camera up axis.
            downscale: train on images shrunk by this integer factor (captures are still added,
                and stored, at the dataset's full size).
            background: colour behind transparent pixels, RGB in [0, 1].
            device: torch device for the NeRF.
            progress: show training progress bars.

        Raises:
            DatasetError: the dataset is missing or malformed (naming the file, frame and value).
            SessionError: `run_dir` already holds a session.
            FolderRefused: `run_dir` is not empty and was not made by nerfaug, holds the dataset
                or lies inside it, or is a session folder that lost its session.json.
        """
        from nerfaug.nerf.config import NerfConfig

        data_dir, run_dir = Path(data_dir).resolve(), Path(run_dir)
        if (run_dir / SESSION_FILE).exists():
            raise SessionError(
                f"{run_dir} already holds a capture session; open it with CaptureSession.open "
                "(`nerfaug train RUN` trains it further)"
            )
        check_new_run(data_dir, run_dir)
        seed, split = check_seed(seed), check_split(split)
        if radius is not None:
            radius = check_radius(radius)
        if int(downscale) < 1:
            raise ValueError(f"downscale must be a positive integer, got {downscale}")
        if len(background) != 3 or not all(0 <= float(c) <= 1 for c in background):
            raise ValueError(f"background must be three numbers in [0, 1], got {background}")
        source = find_split(data_dir, split)
        views = source.load(lazy=True)  # validates the listing and every path
        cameras = views.cameras
        for a, b in duplicate_frames(cameras, views.names):
            same = f"{source.listing}: frames {a} and {b} have the same pose (the same view twice)"
            warnings.warn(same, DuplicateViews, stacklevel=2)
        if int(downscale) > min(cameras.width, cameras.height):
            raise ValueError(
                f"downscale must be at most the image size ({cameras.width}x{cameras.height}), got {downscale}"
            )
        store = plainest_format(source, cameras)
        hemisphere = estimate_hemisphere(cameras.camera_to_world, centre, radius, up)
        preset_name = preset if config is None else "custom"
        config = config if config is not None else NerfConfig.preset(preset)

        # Everything is checked: from here on the run folder is written, and marked as nerfaug's first;
        # a failure (an unreadable image, Ctrl-C) removes what was written, leaving no half-made session.
        existed = run_dir.exists()
        owned.mark(run_dir, RUN_KIND)
        settings = {
            "seed": seed,
            "downscale": downscale,
            "background": background,
            "centre": centre,
            "radius": radius,
            "up": up,
            "data_dir": data_dir,
            "split": split,
            "preset": preset_name,
        }
        try:
            return cls._build(run_dir, source, cameras, store, hemisphere, config, device, progress, settings)
        except BaseException:
            _remove_unfinished(run_dir, existed)
            raise

    @classmethod
    def _build(cls, run_dir, source, cameras, store, hemisphere, config, device, progress, settings: dict):
        """`create`'s writing half, once everything is checked: the dataset copy, the state, the NeRF."""
        from nerfaug.nerf.trainer import Trainer

        seed, downscale, background = settings["seed"], settings["downscale"], settings["background"]
        centre, radius, up, data_dir, split = (settings[k] for k in ("centre", "radius", "up", "data_dir", "split"))
        # The dataset folder is new: check_new_run refused a run folder holding anything.
        dataset = DatasetSplit(run_dir / DATASET_DIR, store, DATASET_SPLIT)
        owned.mark(dataset.root, DATASET_KIND)
        store.copy(source, dataset.root, DATASET_SPLIT)

        state = SessionState(
            source=SourceInfo(str(data_dir), split, source.format.name),
            dataset=DatasetInfo.of(store),
            preset=settings["preset"],
            engine=config.to_dict(),
            seed=int(seed),
            downscale=int(downscale),
            background=tuple(float(c) for c in background),
            intrinsics=Intrinsics(
                cameras.width,
                cameras.height,
                float(cameras.fx[0]),
                float(cameras.fy[0]),
                float(cameras.cx[0]),
                float(cameras.cy[0]),
                float(cameras.camera_angle_x[0]),
            ),
            hemisphere=hemisphere,
            hemisphere_estimated={"centre": centre is None, "radius": radius is None, "up": isinstance(up, str)},
        )
        state.integrity.captures = integrity.capture_digests(dataset, dataset.frames())
        session = cls(run_dir, None, state)
        views = session.engine_views(0)
        session.trainer = Trainer(
            views, config, seed=int(seed), device=device, background=tuple(background), progress=progress
        )
        session.state.views_in_model = len(views)
        session.save()
        return session

    @classmethod
    def open(cls, run_dir: str | Path, device="cpu", progress: bool = False, load_model: bool = True) -> CaptureSession:
        """Reopen a session where `save()` left it (plus any views added after that save).

        Args:
            load_model: False skips the checkpoint: enough to read the state or `export`, not to
                train or propose.

        Raises:
            SessionError: naming the missing or inconsistent file, or the field of session.json
                that is missing, malformed or points outside the run folder.
        """
        from nerfaug.nerf.trainer import Trainer

        run_dir = Path(run_dir)
        state = SessionState.read(run_dir)
        session = cls(run_dir, None, state)
        dataset = session.dataset_split()  # checks it stays inside the run folder
        integrity.check_captures(dataset, session.frames(), state.integrity.captures)
        if not load_model:
            return session
        checkpoint = run_dir / CHECKPOINT_FILE
        if not checkpoint.exists():
            raise SessionError(f"{checkpoint}: checkpoint not found; the run folder is incomplete")
        integrity.check_checkpoint(checkpoint, state.integrity)
        try:
            trainer = Trainer.load_checkpoint(checkpoint, device=device, progress=progress)
        except Exception as error:  # noqa: BLE001 -- torch.load and the state dicts raise many types
            reason = str(error).split(".")[0][:160]
            raise SessionError(
                f"{checkpoint}: cannot load the checkpoint ({type(error).__name__}: {reason}); "
                "restore it from a backup, or start a new session with `nerfaug train DATA --out "
                "NEW_RUN`"
            ) from None
        session.trainer = trainer
        in_model = len(trainer.train_views)
        session._saved = (trainer.step, in_model)
        frames = session.frames()
        if state.integrity.checkpoint is None:
            integrity.check_unrecorded_checkpoint(checkpoint, trainer, state.seed, state.engine, frames)
        if len(frames) < in_model:
            raise SessionError(
                f"{dataset.listing} lists {len(frames)} frames but the checkpoint was "
                f"trained on {in_model}: the dataset was edited outside the session"
            )
        if len(frames) > in_model:  # added after the last save: train on them too
            trainer.add_views(session.engine_views(in_model))
            added = integrity.capture_digests(dataset, frames[in_model:], start=in_model)
            state.integrity.captures.update({k: v for k, v in added.items() if k not in state.integrity.captures})
        state.views_in_model = len(frames)
        state.step = trainer.step
        return session

    def save(self) -> Path:
        """Write the checkpoint (when the model changed since the last save) and session.json.

        Returns the run folder.
        """
        self.require_model()
        current = (self.trainer.step, len(self.trainer.train_views))
        self.state.step = self.trainer.step
        self.state.views_in_model = len(self.trainer.train_views)
        self.state.saved = now()
        if self._saved != current or not (self.run_dir / CHECKPOINT_FILE).exists():
            data = integrity.checkpoint_bytes(self.trainer)
            # The new digest is recorded before the file is replaced: killed between the two
            # writes, the session still recognises whichever checkpoint is on disk as its own.
            self.state.integrity.pending = integrity.sha256_bytes(data)
            atomic_write_json(self.run_dir / SESSION_FILE, self.state.to_dict())
            atomic_write_bytes(self.run_dir / CHECKPOINT_FILE, data)
            self.state.integrity.checkpoint, self.state.integrity.pending = self.state.integrity.pending, None
            self._saved = current
        atomic_write_json(self.run_dir / SESSION_FILE, self.state.to_dict())
        return self.run_dir

    # -- what the session holds --

    @property
    def step(self) -> int:
        return self.trainer.step

    @property
    def seed(self) -> int:
        return self.state.seed

    @property
    def hemisphere(self) -> Hemisphere:
        return self.state.hemisphere

    @property
    def dataset_dir(self) -> Path:
        return self.run_dir / DATASET_DIR

    @property
    def proposals(self) -> list[ProposalRecord]:
        """The proposal history (one record per `propose` call), as stored in session.json."""
        return self.state.proposals

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
        k = self.state.intrinsics
        camera = Cameras(torch.eye(4), k.fx, k.fy, k.cx, k.cy, k.width, k.height)
        return camera if width is None else camera.resized(width, height)

    def require_model(self) -> None:
        if self.trainer is None:
            raise SessionError(f"{self.run_dir} was opened with load_model=False; open it with the model to do this")

    def dataset_split(self) -> DatasetSplit:
        """The grown dataset's split in its format; SessionError if its listing lies outside the run folder."""
        dataset = DatasetSplit(self.dataset_dir, FORMATS[self.state.dataset.format], DATASET_SPLIT)
        path = dataset.listing
        if not owned.overlaps(path, self.run_dir) or path.resolve() == self.run_dir.resolve():
            raise SessionError(
                f"{self.run_dir / SESSION_FILE}, field 'dataset.json': the dataset file must lie "
                f"inside the run folder (got {str(path.resolve())!r})"
            )
        return dataset

    def frames(self) -> list:
        """The frames listed by the dataset (DatasetError unless a list)."""
        return self.dataset_split().frames()

    def engine_views(self, start: int) -> Views:
        """Dataset frames `start:` loaded as the trainer sees them: downscaled, engine frame."""
        state = self.state
        return engine_views(self.dataset_split(), start, state.downscale, state.background, self.hemisphere)

    # -- the loop --

    def train(self, steps: int, callback: Callable[[dict], None] | None = None) -> dict:
        """Train `steps` more steps. Returns the last history entry ({"step", "loss", "psnr"}).

        A session made or opened with `progress=True` shows a progress bar (lines where stderr is
        not a terminal); `callback`, when given, is called every 10 steps and at the last with
        that step's history entry, e.g. `session.train(500, callback=print)`.
        """
        self.require_model()
        self.trainer.train(self.trainer.step + check_steps(steps), callback=callback)
        return self.trainer.history[-1] if self.trainer.history else {"step": self.trainer.step}

    def candidate_cameras(
        self, candidates=None, n_candidates: int = 500, generator: torch.Generator | None = None
    ) -> Cameras:
        """The world-frame candidate cameras for `propose` (see its `candidates`), without the
        poses the model already trains on."""
        return choose.candidate_cameras(self.session_model(), candidates, n_candidates, generator)

    def propose(
        self,
        n: int = 6,
        method: str = "ours",
        candidates=None,
        n_candidates: int = 500,
        generator: torch.Generator | None = None,
        seed: int | None = None,
        config=None,
        map: bool = True,
        constraints=None,
        min_separation: float = 0.0,
    ) -> Proposal:
        """Choose `n` views to capture next.

        Args:
            n: how many views.
            method: a selection method (`nerfaug.selection.METHODS`; "ours" is the paper's).
            candidates: where views may be taken from. None or "hemisphere": `n_candidates`
                poses uniform on the session's hemisphere (minus the training views); Cameras or
                an (C, 4, 4) array of world-frame poses (e.g. what a robot can reach; the
                session's intrinsics are used for poses); or a path to a transforms JSON of them.
            n_candidates: hemisphere candidates to draw.
            generator: random source for the candidates and the selector; None seeds one from
                the session seed and the proposal number (`proposal_seed`), so a resumed session
                proposes exactly what the original would have.
            seed: seed a generator with this instead.
            config: a `nerfaug.selection.SelectionConfig` (or its `to_dict()`); None for the
                paper's defaults. The method's own settings apply over it; what was used is
                recorded with the proposal (`extra["selection"]` of its history record).
            map: draw the hemisphere map to `run/proposals/proposal_NNN.png`.
            constraints: a `ViewConstraints` (or its `to_dict()`): elevation, azimuth and radius
                ranges and keep-out cones the candidates must satisfy (recorded with the proposal).
            min_separation: degrees; > 0 keeps every two proposed views at least this far apart
                about the hemisphere's centre (recorded with the proposal). 0, the default,
                proposes exactly what the method chooses.

        Returns:
            Proposal (world-frame poses, names, angles, every candidate's score, map path). The
            proposal is recorded in the history (saved with `save()`) and written, with its
            candidates, to `run/proposals/proposal_NNN.json`.

        Raises:
            TooFewCandidates (a ValueError): the constraints leave fewer candidates than `n`.
        """
        request = choose.ProposalRequest(
            n, method, candidates, n_candidates, seed, config, map, constraints, min_separation
        )
        folder = self.run_dir / PROPOSALS_DIR
        number = len(self.state.proposals)
        shown = bool(self.trainer is not None and self.trainer.progress)  # as the session was opened
        proposal, record = choose.propose(request, self.session_model(), number, folder, generator, shown)
        self.state.proposals.append(record)
        return proposal

    def session_model(self) -> SessionModel:
        """What the steps that use the NeRF need of this session (`SessionModel`)."""
        self.require_model()
        return SessionModel(
            model=self.trainer.model,
            device=self.trainer.device,
            train_cameras=self.trainer.train_views.cameras,
            step=self.step,
            hemisphere=self.hemisphere,
            template=self.template(),
            background=tuple(self.state.background),
            seed=self.seed,
        )

    def add_views(self, images, poses=None, names: Sequence[str] | None = None) -> list[str]:
        """Add captured images, taken at world-frame `poses`, to the dataset and to training.

        Everything is checked before anything is written; on any error the dataset folder is
        left exactly as it was. Then the images are written, then the transforms JSON (atomically).

        Args:
            images: a folder (matched to the poses' names by file stem when the poses come from
                a transforms JSON or a Proposal, else every image file in it, sorted by name); a
                list of image files and/or arrays; an array or tensor (n, H, W, 3 | 4) of uint8,
                uint16 or float in [0, 1] (RGBA alpha is kept); or `Views` (e.g. an oracle's
                capture, composited over the session's background; its cameras' poses are used
                when `poses` is None).
            poses: world-frame camera-to-world poses: an (n, 4, 4) array or tensor, a `Proposal`,
                or a path to a transforms JSON (e.g. one `Proposal.write` made).
            names: image names (file stems) for the new frames; by default the poses' frame
                names, else the files' stems, else `view_NNNN`.

        Returns:
            The new frames' names.

        Raises:
            DatasetError: naming the file or index and the value: count mismatch, wrong image
                size, unreadable file, values out of range, non-rigid pose, duplicate name.
        """
        self.require_model()
        dataset, camera = self.dataset_split(), self.template()
        addition = add.prepare_addition(images, poses, names, dataset, camera, self.state.background)
        start = len(dataset.frames())
        self.state.integrity.captures.update(add.write_addition(addition, dataset, camera))
        self.trainer.add_views(self.engine_views(start))
        self.state.views_in_model = len(self.trainer.train_views)
        matched = [p.number for p in self.state.proposals if set(addition.names) <= set(p.names)]
        record = AdditionRecord(
            step=self.step,
            names=list(addition.names),
            proposal=matched[-1] if matched else None,
            created=now(),
            extra={"warnings": list(addition.warnings)} if addition.warnings else {},
        )
        self.state.additions.append(record)
        return list(addition.names)

    def render(self, poses, width: int | None = None) -> Tensor:
        """What the NeRF sees from world-frame `poses` (n, 4, 4): images (n, H, W, 3) in [0, 1],
        at the training resolution (or `width` pixels across)."""
        return self.session_model().render(poses, width)

    def uncertainty_maps(
        self,
        poses,
        width: int | None = None,
        fisher: bool = True,
        fisher_width: int = 16,
        progress: bool = False,
        names: Sequence[str] | None = None,
    ) -> list[ViewMaps]:
        """The render, depth, ray entropy and FisherRF images of world-frame `poses` (n, 4, 4);
        see `nerfaug.capture.uncertainty_images.view_maps` (`progress` shows each view's images
        as they are done, named by `names`)."""
        return view_maps(self.session_model(), poses, width, fisher, fisher_width, progress, names)

    def held_out(self, data: str | Path, split: str = "test", max_views: int | None = None) -> Views:
        """`split` of the dataset folder `data` (same scene and world frame) at the training
        resolution, over the session's background: what `evaluate` scores."""
        return load_held_out(data, check_split(split), self.state.downscale, self.state.background, max_views)

    def evaluate(self, views: Views, lpips="auto", progress: bool = False) -> EvaluationResult:
        """PSNR, SSIM and LPIPS of the NeRF's renders of world-frame `views` (`held_out`) against
        their images; see `nerfaug.capture.evaluate.evaluate_model`."""
        return evaluate_model(self.session_model(), views, lpips, progress)

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


def _remove_unfinished(run_dir: Path, existed: bool) -> None:
    """Remove what a failed `create` wrote: the run folder, or its contents when it was there
    before (empty or only nerfaug's marker: `check_new_run` refused anything else)."""
    import shutil

    if not existed:
        shutil.rmtree(run_dir, ignore_errors=True)
        return
    for path in run_dir.iterdir():
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)
