"""Whether a run folder's checkpoint and captured images are the ones its session wrote: their
sha256 digests, recorded in session.json (`Integrity`), checked when the session is opened.

A session trains on what it finds in its folder; a checkpoint copied in from another session, or
an image deleted or edited by hand, would silently change what it is. Each check names the file
and what changed, and says what to do.
"""

from __future__ import annotations

import hashlib
import io
import json
import warnings
from pathlib import Path

import torch

from nerfaug.capture.runfolder import SESSION_FILE
from nerfaug.capture.state import Integrity, SessionError, UnverifiedCheckpoint
from nerfaug.data.errors import DatasetError
from nerfaug.data.interface import DatasetSplit
from nerfaug.nerf.config import NerfConfig

_RESTORE = "put the session's own file back, or start a new session with `nerfaug train DATA --out NEW_RUN`"


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def sha256_file(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def checkpoint_bytes(trainer) -> bytes:
    """The trainer's whole state (`Trainer.state_dict`) as `torch.save` writes it: hashed, then
    written, so the digest is of exactly the bytes on disk."""
    buffer = io.BytesIO()
    torch.save(trainer.state_dict(), buffer)
    return buffer.getvalue()


def check_checkpoint(path: Path, data: bytes, integrity: Integrity) -> None:
    """Refuse a checkpoint (`data`, the bytes of the file `path`) the session did not write (no-op
    for sessions saved before digests were kept).

    Raises:
        SessionError: naming the checkpoint, its digest and the one session.json records.
    """
    if integrity.checkpoint is None:
        return
    found = sha256_bytes(data)
    if found not in (integrity.checkpoint, integrity.pending):
        raise SessionError(
            f"{path}: not this session's checkpoint (sha256 {found[:12]}..., session.json records "
            f"{integrity.checkpoint[:12]}...): it was replaced, e.g. copied from another session; {_RESTORE}"
        )


def check_unrecorded_checkpoint(path: Path, trainer, seed: int, engine: dict, frames: list) -> None:
    """For a session saved before digests were kept: refuse a checkpoint whose seed, engine or
    training views are not the session's (e.g. copied from another session), else warn
    (`UnverifiedCheckpoint`) that it could not be checked by content.

    Args:
        path: the checkpoint file.
        trainer: the `Trainer` loaded from it.
        seed, engine: the session's seed and engine settings (session.json).
        frames: the session dataset's frames, in order.

    Raises:
        SessionError: naming the checkpoint and what differs.
    """
    names = [str(f.get("file_path")) if isinstance(f, dict) else "?" for f in frames]
    trained = [str(n) for n in trainer.train_views.names]
    # Both by flat name, as JSON holds them (lists, not tuples): session.json holds the nested
    # settings, or the flat ones where an earlier nerfaug wrote it.
    config = json.loads(json.dumps(trainer.config.flat()))
    engine = json.loads(json.dumps(NerfConfig.from_dict(engine).flat()))
    differs = [k for k in sorted(set(config) & set(engine)) if config[k] != engine[k]]
    problem = None
    if int(trainer.seed) != int(seed):
        problem = f"its seed is {trainer.seed}, the session's {seed}"
    elif differs:
        problem = f"its engine setting {differs[0]!r} is {config[differs[0]]!r}, the session's {engine[differs[0]]!r}"
    elif trained[: len(names)] != names[: len(trained)]:
        i = next(i for i, (a, b) in enumerate(zip(trained, names)) if a != b)
        problem = f"it was trained on view {trained[i]!r} where the session's dataset has {names[i]!r}"
    if problem is not None:
        raise SessionError(
            f"{path}: not this session's checkpoint ({problem}): it was replaced, e.g. copied from another "
            f"session; {_RESTORE}"
        )
    warnings.warn(
        f"{path}: {SESSION_FILE} records no digest of it (saved by an earlier nerfaug), so it is used as found; "
        "its digest is recorded at the next save",
        UnverifiedCheckpoint,
        stacklevel=4,
    )


def capture_digests(dataset: DatasetSplit, frames: list, start: int = 0) -> dict[str, str]:
    """Each frame's `file_path` -> the digest of its image file (found as the dataset reader finds
    it); `start` numbers the frames in error messages."""
    files = dataset.frame_files(frames, start)
    return {str(frame["file_path"]): sha256_file(path) for frame, path in zip(frames, files)}


def check_captures(dataset: DatasetSplit, frames: list, recorded: dict[str, str]) -> None:
    """Refuse a dataset whose recorded images were deleted, edited or unlisted since the session stored them.

    Frames without a recorded digest (added after the last save) are not checked here.

    Raises:
        SessionError: naming the first image (or transforms entry) that changed and how.
    """
    listed = {str(frame["file_path"]): i for i, frame in enumerate(frames)}
    for file_path, digest in recorded.items():
        if file_path not in listed:
            raise SessionError(
                f"{dataset.listing} lists {len(frames)} frames, without the captured view {file_path!r}, one of the "
                f"{len(recorded)} {SESSION_FILE} records (the dataset was edited outside the session); {_RESTORE}"
            )
        index = listed[file_path]
        try:
            path = dataset.frame_files([frames[index]], start=index)[0]
        except DatasetError as error:
            raise SessionError(
                f"{error}: the captured image was deleted or moved since nerfaug stored it; {_RESTORE}"
            ) from None
        found = sha256_file(path)
        if found != digest:
            raise SessionError(
                f"{path}: the captured image of frame {index} changed since nerfaug stored it (sha256 "
                f"{found[:12]}..., recorded {digest[:12]}...); {_RESTORE}"
            )
