"""`CaptureSession`: train a NeRF on the views you have, ask which views to capture next, add the
images you captured there (a robot, a phone, a simulator), and go on training.

A session lives in a run folder:

    run/
      .nerfaug              marker: nerfaug made this folder (nothing is removed from a folder without it)
      .lock                 who changes the session now (`nerfaug.capture.lock`; the commands and the service)
      session.json          state (`SessionState`): step, seed, engine, intrinsics, hemisphere, proposals, additions
      checkpoint.pt         the trainer (`Trainer.save_checkpoint`): model, optimiser, RNG, views
      dataset/              the dataset as it has grown, as the train split of a registered format
                              (`nerfaug.data.FORMATS`): Blender when one camera_angle_x describes its
                              cameras, else the source's own (nerfstudio: `transforms.json` + `images/*`)
      proposals/            proposal_000.json (poses + every candidate's score), proposal_000.png (map)

Poses given to and returned by a session are in the dataset's world frame; the NeRF is trained in
the engine frame of the session's hemisphere (`nerfaug.data.world_frame`).
"""

from __future__ import annotations

import contextlib
import functools
import io
import math
import tempfile
import warnings
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from time import monotonic

import torch
from torch import Tensor

from nerfaug import owned, runfiles
from nerfaug.cameras import Cameras
from nerfaug.capture import add, choose, integrity
from nerfaug.capture.dataset import default_split, duplicate_frames, sparse_start
from nerfaug.capture.evaluate import evaluate_model
from nerfaug.capture.folder import SessionFolder, camera_of
from nerfaug.capture.images import ImageFile, check_image_files, write_files
from nerfaug.capture.model import SessionModel
from nerfaug.capture.proposal import Proposal
from nerfaug.capture.proposal_request import ProposalRequest
from nerfaug.capture.requests import (
    CHECKPOINT_EVERY_S,
    FISHER_WIDTH,
    Intrinsics,
    SessionSettings,
    SparseStart,
    Split,
    as_pose_list,
    check_checkpoint_every,
    check_steps,
    validated,
    words,
)
from nerfaug.capture.runfolder import (
    CHECKPOINT_FILE,
    DATASET_DIR,
    DATASET_KIND,
    DATASET_SPLIT,
    POOL_FILE,
    PROPOSALS_DIR,
    RUN_KIND,
    SESSION_FILE,
    UNFINISHED_FILE,
    check_new_run,
    remove_unfinished,
)
from nerfaug.capture.state import (
    AdditionRecord,
    DuplicateViews,
    SessionError,
    SessionState,
    SessionSummary,
    SourceInfo,
    TiltedPole,
    new_state,
    now,
    pole_settings,
)
from nerfaug.capture.uncertainty_images import ViewMaps, view_maps
from nerfaug.data.formats import EXCHANGE_FORMAT, FORMATS, find_split, get_format
from nerfaug.data.interface import DatasetSplit, NewFrame
from nerfaug.data.views import Views
from nerfaug.data.world_frame import TILTED_POLE_DEGREES, estimate_hemisphere, pole_tilt_degrees
from nerfaug.evaluation import EvaluationResult
from nerfaug.health import EmptyModel, EmptyModelWarning, Health, model_health
from nerfaug.nerf.config import NerfConfig
from nerfaug.nerf.engine import Engine
from nerfaug.nerf.trainer import Trainer
from nerfaug.progress import progress_bar
from nerfaug.selection import select_views

CHUNK_STEPS = 10  # training steps between looks at the clock and at `stop`


class CaptureSession(SessionFolder):
    """Active capture over a dataset folder and a run folder; see the module docstring.

    Make one with `create` (from a dataset), `from_files` (from images as captured) or `open` (a
    run folder), not the constructor. Changes to the model and the proposal history are kept in
    memory until `save()`; `add_views` writes the grown dataset at once (it is the data), and `open`
    re-reads views the checkpoint has not seen yet, so nothing captured is ever lost.

    Example:
        >>> settings = SessionSettings(engine="cpu")
        >>> session = CaptureSession.create("data/lego", "runs/lego", settings, split="initial")  # doctest: +SKIP
        >>> session.train(1000)                                      # doctest: +SKIP
        >>> proposal = session.propose(ProposalRequest(n=6))         # doctest: +SKIP
        >>> proposal.write("poses.json")                             # doctest: +SKIP
        >>> session.add_views("captures/", "poses.json")             # doctest: +SKIP
        >>> session.train(1000); session.save()                      # doctest: +SKIP
    """

    def __init__(self, run_dir: Path, state: SessionState, trainer: Trainer):
        super().__init__(run_dir, state)
        self.trainer = trainer
        self._saved: tuple[int, int] | None = None  # (step, views) of the checkpoint on disk

    # -- creation and persistence --

    @classmethod
    def create(
        cls,
        data_dir: str | Path,
        run_dir: str | Path,
        settings: SessionSettings | None = None,
        *,
        split: str | None = None,
        config: NerfConfig | None = None,
        background=(1.0, 1.0, 1.0),
        device="cpu",
        progress: bool = False,
        warn: Callable[[str, type[Warning]], None] | None = None,
        source_name: str | None = None,
        start: SparseStart | None = None,
    ) -> CaptureSession:
        """Start a session: copy `split` of the dataset into `run_dir/dataset`, build the NeRF,
        save. Nothing is trained yet (call `train`).

        Args:
            data_dir: a dataset folder in a registered format (`nerfaug.data.FORMATS`: Blender's
                `transforms_{split}.json`, nerfstudio's `transforms.json`): the views captured so far.
            run_dir: the run folder to create (must not hold a session already).
            settings: the engine, seed, downscale factor and hemisphere (`SessionSettings`;
                its centre, radius or pole estimated from the cameras where not given).
            split: the split holding the captured views; None: `default_split` ("initial" for a
                dataset `nerfaug scene render` wrote, else "train").
            config: a `NerfConfig` to use instead of the settings' engine.
            background: colour behind transparent pixels, RGB in [0, 1].
            device: torch device for the NeRF.
            progress: show training progress bars.
            warn: receives each warning (message, `DuplicateViews` or `TiltedPole`) instead of
                Python's `warnings` (a service returns them with its answer).
            source_name: how warnings name the views' listing (default: its file).
            start: a sparse start (`SparseStart`): only `start.initial` views of the split, on one
                half of the object (the hemisphere is estimated from every view), are copied; the
                others' poses and names become the candidate pool `propose` chooses from by
                default (`run_dir/pool.json`), so `add` takes their images from the dataset.

        Raises:
            RequestError: a setting out of range (naming it).
            DatasetError: the dataset is missing or malformed (naming the file, frame and value).
            SessionError: `run_dir` already holds a session.
            FolderRefused: `run_dir` is not empty and was not made by nerfaug, holds the dataset
                or lies inside it, or is a session folder that lost its session.json.
        """
        data_dir, run_dir = Path(data_dir).resolve(), Path(run_dir)
        if runfiles.exists(run_dir, SESSION_FILE):
            raise SessionError(
                f"{run_dir} already holds a capture session; open it with CaptureSession.open "
                "(`nerfaug train RUN` trains it further)"
            )
        check_new_run(data_dir, run_dir)
        settings = (settings or SessionSettings()).checked()
        split = validated(Split, default_split(data_dir)[0] if split is None else split, "split")
        if len(background) != 3 or not all(0 <= float(c) <= 1 for c in background):
            raise ValueError(f"background must be three numbers in [0, 1], got {background}")
        source = find_split(data_dir, split)
        views = source.load(lazy=True)  # validates the listing and every path
        cameras = views.cameras
        listing = source_name or str(source.listing)
        warn = warn or functools.partial(warnings.warn, stacklevel=2)
        for a, b in duplicate_frames(cameras, views.names):
            warn(f"{listing}: frames {a} and {b} have the same pose (the same view twice)", DuplicateViews)
        if settings.downscale > min(cameras.width, cameras.height):
            raise ValueError(
                f"downscale must be at most the image size ({cameras.width}x{cameras.height}), got {settings.downscale}"
            )
        settings = pole_settings(settings, source, cameras)
        up = "estimate" if settings.estimate_up else (settings.up or (0.0, 0.0, 1.0))
        hemisphere = estimate_hemisphere(cameras.camera_to_world, settings.centre, settings.radius, up)
        tilt = None if settings.estimate_up else pole_tilt_degrees(cameras.camera_to_world, hemisphere.up)
        if tilt is not None and tilt > TILTED_POLE_DEGREES:
            warn(
                f"{listing}: the cameras' mean up axis is {tilt:.0f} degrees from the hemisphere's pole "
                f"(--up {words(hemisphere.up)}), so the candidate views would lie on a tilted hemisphere; if this "
                "world is not z-up (LLFF, COLMAP and DTU frames seldom are), create the session with --estimate-up "
                "or --up X Y Z",
                TiltedPole,
            )
        pool = record = None
        if start is not None:
            start = validated(SparseStart, start, "start")
            source, cameras, pool, record = sparse_start(source, views, hemisphere, start)
        origin = SourceInfo(data_dir=str(data_dir), split=split, format=source.format.name)
        engine = Engine.read(settings.engine)  # an Engine as it is: resolved where the request entered
        engine, config = (engine, engine.config) if config is None else ("custom", config)
        state = new_state(origin, source, cameras, settings, engine, config, background, hemisphere)
        if pool is not None:
            state.start, state.pool = record, POOL_FILE
        # Everything is checked: from here on the run folder is written, and marked as nerfaug's first;
        # a failure (an unreadable image, Ctrl-C) removes what was written, leaving no half-made session.
        existed = run_dir.exists()
        owned.mark(run_dir, RUN_KIND)
        try:
            runfiles.write_bytes(run_dir, UNFINISHED_FILE, b"")  # until session.json is written (`check_new_run`)
            if pool is not None:
                runfiles.write_json(run_dir, POOL_FILE, pool)
            session = cls._build(run_dir, source, state, config, device, progress)
            runfiles.path_in(run_dir, UNFINISHED_FILE).unlink()
            return session
        except BaseException:
            remove_unfinished(run_dir, existed)
            raise

    @classmethod
    def _build(cls, run_dir: Path, source: DatasetSplit, state: SessionState, config, device, progress: bool):
        """`create`'s writing half, once everything is checked: the dataset copy, the NeRF, the save."""
        # The dataset folder is new: check_new_run refused a run folder holding anything.
        store = FORMATS[state.dataset.format]
        dataset = DatasetSplit(runfiles.path_in(run_dir, DATASET_DIR), store, DATASET_SPLIT)
        owned.mark(dataset.root, DATASET_KIND)
        store.copy(source, dataset.root, DATASET_SPLIT)
        state.integrity.captures = integrity.capture_digests(dataset, dataset.frames())
        views = SessionFolder(run_dir, state).engine_views(0)
        trainer = Trainer(
            views, config, seed=state.seed, device=device, background=tuple(state.background), progress=progress
        )
        session = cls(run_dir, state, trainer)
        session.state.views_in_model = len(views)
        session.save()
        return session

    @classmethod
    def from_files(
        cls,
        files: Sequence[ImageFile],
        poses,
        intrinsics: Intrinsics,
        run_dir: str | Path,
        settings: SessionSettings | None = None,
        *,
        device="cpu",
        progress: bool = False,
        warn: Callable[[str, type[Warning]], None] | None = None,
    ) -> CaptureSession:
        """Start a session on images as captured (their files' bytes, e.g. uploaded), taken at
        world-frame `poses` (one each, in order) with one camera, `intrinsics`; see `create`
        (its warnings name the views "the poses").
        Every file is checked (`check_image_files`: names, and RGB(A) pixels of the camera's size)
        before anything is written."""
        check_image_files(files, intrinsics.width, intrinsics.height)
        poses = as_pose_list(poses)
        if len(poses) != len(files):
            raise ValueError(f"poses: {len(poses)} poses for {len(files)} images; give one pose per image")
        frames = [NewFrame(f.name, f.data, f.suffix, pose) for f, pose in zip(files, poses)]
        settings = settings or SessionSettings()
        if settings.estimate_up is None:  # poses given in the caller's world, z-up unless it says (warned otherwise)
            settings = replace(settings, estimate_up=False)
        with tempfile.TemporaryDirectory(prefix="nerfaug-captures-") as staging:
            data = DatasetSplit(Path(staging) / "data", get_format(EXCHANGE_FORMAT))
            data.append(frames, camera_of(intrinsics))
            return cls.create(
                data.root,
                run_dir,
                settings,
                split=DATASET_SPLIT,
                device=device,
                progress=progress,
                warn=warn,
                source_name="the poses",
            )

    @classmethod
    def open(cls, run_dir: str | Path, device="cpu", progress: bool = False) -> CaptureSession:
        """Reopen a session where `save()` left it (plus any views added after that save).
        (`SessionFolder.open` reads it without its model.)

        Raises:
            SessionError: naming the missing or inconsistent file, or the field of session.json
                that is missing, malformed or points outside the run folder.
        """
        folder = SessionFolder.open(run_dir)
        data, checkpoint = folder.checkpoint(), runfiles.shown(run_dir, CHECKPOINT_FILE)
        try:
            trainer = Trainer.load_checkpoint(io.BytesIO(data), device=device, progress=progress)
        except Exception as error:  # noqa: BLE001 -- torch.load and the state dicts raise many types
            reason = str(error).split(".")[0][:160]
            raise SessionError(
                f"{checkpoint}: cannot load the checkpoint ({type(error).__name__}: {reason}); "
                "restore it from a backup, or start a new session with `nerfaug train DATA --out "
                "NEW_RUN`"
            ) from None
        session = cls(folder.run_dir, folder.state, trainer)
        session._catch_up(checkpoint, data)
        return session

    def _catch_up(self, checkpoint: Path, data: bytes) -> None:
        """After loading the checkpoint: check it against the dataset, and train on the views added
        after it was saved too."""
        state, trainer = self.state, self.trainer
        in_model = len(trainer.train_views)
        self._saved = (trainer.step, in_model)
        frames = self.frames()
        if state.integrity.checkpoint is None:
            integrity.check_unrecorded_checkpoint(checkpoint, trainer, state.seed, state.engine_config, frames)
            # Accepted as found: its digest is saved at the next save, new model or not (else every open warns).
            state.integrity.checkpoint = integrity.sha256_bytes(data)
        if len(frames) < in_model:
            raise SessionError(
                f"{self.dataset_split().listing} lists {len(frames)} frames but the checkpoint was "
                f"trained on {in_model}: the dataset was edited outside the session"
            )
        if len(frames) > in_model:  # added after the last save: train on them too, each in a record
            if (record := add.unrecorded_addition(state, frames[in_model:], trainer.step)) is not None:
                state.additions.append(record)
            trainer.add_views(self.engine_views(in_model))
            added = integrity.capture_digests(self.dataset_split(), frames[in_model:], start=in_model)
            state.integrity.captures.update({k: v for k, v in added.items() if k not in state.integrity.captures})
        state.views_in_model = len(frames)
        state.step = trainer.step

    def save(self) -> Path:
        """Write the checkpoint (when the model changed since the last save) and session.json; the run folder."""
        current = (self.trainer.step, len(self.trainer.train_views))
        self.state.step = self.trainer.step
        self.state.views_in_model = len(self.trainer.train_views)
        self.state.saved = now()
        if self._saved != current or not runfiles.exists(self.run_dir, CHECKPOINT_FILE):
            data = integrity.checkpoint_bytes(self.trainer)
            # The new digest is recorded before the file is replaced: killed between the two
            # writes, the session still recognises whichever checkpoint is on disk as its own.
            self.state.integrity.pending = integrity.sha256_bytes(data)
            runfiles.write_json(self.run_dir, SESSION_FILE, self.state.to_dict())
            runfiles.write_bytes(self.run_dir, CHECKPOINT_FILE, data)
            self.state.integrity.checkpoint, self.state.integrity.pending = self.state.integrity.pending, None
            self._saved = current
        runfiles.write_json(self.run_dir, SESSION_FILE, self.state.to_dict())
        return self.run_dir

    # -- what the session holds --

    @property
    def step(self) -> int:
        return self.trainer.step

    @property
    def saved_step(self) -> int:
        """The step of the checkpoint on disk (the last `save`)."""
        return self._saved[0]

    def summary(self) -> SessionSummary:
        """The session's step, views, last losses, proposals, additions, hemisphere and camera."""
        history, views = self.trainer.history, self.trainer.train_views
        return self._summary(self.step, [str(n) for n in views.names], [dict(h) for h in history[-5:]])

    # -- the loop --

    def train(self, steps: int, callback: Callable[[dict], None] | None = None) -> dict:
        """Train `steps` more steps. Returns the last history entry ({"step", "loss", "psnr"}).

        A session made or opened with `progress=True` shows a progress bar (lines where stderr is
        not a terminal); `callback`, when given, is called every 10 steps and at the last with
        that step's history entry, e.g. `session.train(500, callback=print)`.
        """
        self.trainer.train(self.trainer.step + check_steps(steps), callback=callback)
        return self.trainer.history[-1] if self.trainer.history else {"step": self.trainer.step}

    def train_for(
        self,
        steps: int,
        checkpoint_every: float = CHECKPOINT_EVERY_S,
        stop: Callable[[], bool] = lambda: False,
        *,
        hold: contextlib.AbstractContextManager = contextlib.nullcontext(),
        each: Callable[[dict], None] | None = None,
        log: Callable[[dict], None] | None = None,
    ) -> dict:
        """Train `steps` more steps, `CHUNK_STEPS` at a time, saving once `checkpoint_every`
        seconds passed since the last save, and at the end (also when `stop()` ends it early).
        What the commands and the service run; a second Ctrl-C (KeyboardInterrupt) stops at once,
        keeping the last save (`saved_step`).

        Args:
            hold: held around each chunk and the last save (the service's lock of the session,
                so that its other requests run between chunks).
            each: called after each chunk, holding `hold`, with its last history entry.
            log: called every few steps with that step's history entry (a training log,
                `nerfaug.training_log`).

        Returns:
            The last history entry ({"step", "loss", "psnr"}).

        Raises:
            RequestError: `steps` out of 0..`MAX_STEPS`, or `checkpoint_every` not > 0.
        """
        start, checkpoint_every = self.step, check_checkpoint_every(checkpoint_every)
        target, last, saved_at = start + check_steps(steps), {"step": start}, monotonic()
        shown, self.trainer.progress = self.trainer.progress, False  # one bar over the chunks
        try:
            with progress_bar(fields="psnr {psnr:.2f} dB", enabled=shown) as bar:
                task = bar.add_task("training", total=target - start, psnr=math.nan)
                while True:
                    with hold:
                        if self.step >= target or stop():
                            break
                        last = self.train(min(CHUNK_STEPS, target - self.step), callback=log)
                        bar.update(task, completed=self.step - start, psnr=last.get("psnr", math.nan))
                        if monotonic() - saved_at >= checkpoint_every:
                            self.save()
                            saved_at = monotonic()
                        if each is not None:
                            each(last)
            with hold:
                self.save()
        finally:
            self.trainer.progress = shown
        return last

    def candidate_cameras(self, request: ProposalRequest, generator: torch.Generator | None = None) -> Cameras:
        """The world-frame candidate cameras of `request` (the hemisphere's or its reachable
        poses), without the poses the model already trains on."""
        request = request.checked()
        return choose.candidate_cameras(self.session_model(), request.candidates, request.n_candidates, generator)

    def propose(
        self, request: ProposalRequest | None = None, *, generator: torch.Generator | None = None, map: bool = True
    ) -> Proposal:
        """Choose views to capture next, as `request` asks (`ProposalRequest`: how many, which
        method, which candidates, where they may lie; its defaults: 6 views, "ours", 500
        hemisphere candidates).

        Args:
            generator: random source for the candidates and the selector; None seeds one from
                the request's seed, else from the session seed and the proposal number
                (`proposal_seed`), so a resumed session proposes exactly what the original would have.
            map: draw the hemisphere map to `run/proposals/proposal_NNN.png`.

        Returns:
            Proposal (world-frame poses, names, angles, every candidate's score, map path). The
            proposal is recorded in the history (saved with `save()`) and written, with its
            candidates, to `run/proposals/proposal_NNN.json`.

        Raises:
            RequestError: a value of the request out of range (naming it).
            EmptyModel: the NeRF renders its training views as background only (`health`), and
                the request does not say `allow_empty`: its proposal would say nothing about
                which views would help.
            TooFewCandidates (a ValueError): the constraints leave fewer candidates than asked.

        Warns:
            EmptyModelWarning: as `EmptyModel`, when the request says `allow_empty`.
        """
        number = len(self.state.proposals)
        name = f"{PROPOSALS_DIR}/proposal_{number:03d}"
        poses_file, map_file = (runfiles.path_in(self.run_dir, f"{name}{suffix}") for suffix in (".json", ".png"))
        request = (request or ProposalRequest()).checked()  # once: a request the command or the service checked passes
        model = self.session_model()
        generator, seed = choose.proposal_generator(generator, model.seed, number, request.seed)
        candidates = choose.allowed_candidates(
            model, request.candidates, request.n_candidates, request.constraints, request.n, generator
        )
        # Once the request is found possible (a refused one says only why), before scoring; a few
        # candidates (poses it never trained on) rendered beside the training views, as a report.
        health = self.health(candidates.world)
        if health.empty and not request.allow_empty:
            raise EmptyModel(
                f"{self.run_dir}: no views proposed: {health.line()} (or ask with allow_empty, `--allow-empty`, "
                "to propose from it all the same)"
            )
        engine = choose.engine_cameras(model, candidates.world)
        with progress_bar(enabled=bool(self.trainer.progress), transient=True) as bar:  # as the session was opened
            task = bar.add_task(f"scoring candidates ({request.method})", total=len(engine))
            selection = select_views(
                request.method,
                model.model,
                model.train_cameras,
                engine.to(model.device),
                request.n,
                generator,
                request.selection,
                min_separation=math.radians(request.min_separation),
                progress=lambda done: bar.update(task, completed=done),
            )
            bar.update(task, completed=len(engine))
        map_path = map_file if map else None
        proposal = choose.proposal_of(
            selection, candidates, engine, model, number, seed, request.min_separation, map_path
        )
        proposal.write(poses_file, include_candidates=True)
        file = f"{name}.json"
        record = choose.record_of(proposal, file, candidates.described, selection, request.constraints, health.empty)
        record.health = health.to_dict()  # a further key of the record: what `nerfaug propose` reports
        if health.empty:
            warnings.warn(f"{self.run_dir}: proposed from an empty NeRF: {health.line()}", EmptyModelWarning, 2)
        self.state.proposals.append(record)
        return proposal

    def health(self, untrained: Cameras | None = None) -> Health:
        """Whether the NeRF learned its training views (`nerfaug.health`), with renders of a few
        of `untrained` (world-frame cameras it did not train on) reported beside them."""
        if untrained is not None:
            untrained = choose.engine_cameras(self.session_model(), untrained)
        background = tuple(self.state.background)
        return model_health(self.trainer.model, self.trainer.train_views, background, untrained)

    def session_model(self) -> SessionModel:
        """What the steps that use the NeRF need of this session (`SessionModel`)."""
        return SessionModel(
            model=self.trainer.model,
            device=self.trainer.device,
            train_cameras=self.trainer.train_views.cameras,
            step=self.step,
            hemisphere=self.hemisphere,
            template=self.template(),
            background=tuple(self.state.background),
            seed=self.seed,
            pool=None if self.state.pool is None else runfiles.path_in(self.run_dir, self.state.pool),
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
            **({"warnings": list(addition.warnings)} if addition.warnings else {}),
        )
        self.state.additions.append(record)
        return list(addition.names)

    def add_files(self, files: Sequence[ImageFile], poses) -> list[str]:
        """`add_views` for images as captured (their files' bytes, e.g. uploaded), stored byte for
        byte and named by their stems; one world-frame pose each, in order. Every file is checked
        (`check_image_files`) before anything is written."""
        check_image_files(files, self.state.intrinsics.width, self.state.intrinsics.height)
        with tempfile.TemporaryDirectory(prefix="nerfaug-captures-") as staging:
            return self.add_views(write_files(files, Path(staging)), poses)

    def render(self, poses, width: int | None = None) -> Tensor:
        """What the NeRF sees from world-frame `poses` (n, 4, 4): images (n, H, W, 3) in [0, 1],
        at the training resolution (or `width` pixels across)."""
        return self.session_model().render(poses, width)

    def uncertainty_maps(
        self, poses, width: int | None = None, fisher=True, fisher_width=FISHER_WIDTH, progress=False, names=None
    ) -> list[ViewMaps]:
        """The render, depth, ray entropy and FisherRF images of world-frame `poses` (n, 4, 4):
        `nerfaug.capture.uncertainty_images.view_maps` (`progress`: each view's, named by `names`)."""
        return view_maps(self.session_model(), poses, width, fisher, fisher_width, progress, names)

    def evaluate(self, views: Views, lpips="auto", progress: bool = False) -> EvaluationResult:
        """PSNR, SSIM and LPIPS of the NeRF's renders of world-frame `views` (`held_out`) against
        their images; see `nerfaug.capture.evaluate.evaluate_model`."""
        return evaluate_model(self.session_model(), views, lpips, progress)
