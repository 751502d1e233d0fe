"""Where a session's training is logged while it trains, besides history.json: `--logger`.

    nerfaug train DATA --out RUN --logger tensorboard     then: tensorboard --logdir RUN/tensorboard

"tensorboard" writes each logged step's total loss, every named loss (rgb, interlevel,
distortion) and the training batch's PSNR as TensorBoard scalars, as nerfstudio's
`--vis tensorboard` does; it needs the optional `tensorboard` package (`pip install
'nerfaug[tensorboard]'`). Light: the package is imported only when such a log is opened.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Literal

from nerfaug import runfiles

Logger = Literal["none", "tensorboard"]
"""The loggers `--logger` takes."""

TENSORBOARD_FOLDER = "tensorboard"
"""The folder of a run folder that "tensorboard" writes its event files into."""


class LoggerUnavailable(RuntimeError):
    """The logger asked for needs a package that is not installed."""


def scalars(entry: Mapping) -> dict[str, float]:
    """The scalars a history entry ({"step", "loss", "psnr", "losses"}) is logged as, by tag.

    Example:
        >>> scalars({"step": 10, "loss": 0.5, "psnr": 12.0, "losses": {"rgb": 0.4, "distortion": 0.1}})
        {'train/loss': 0.5, 'train/psnr': 12.0, 'train/loss/rgb': 0.4, 'train/loss/distortion': 0.1}
    """
    tags = {f"train/{name}": float(entry[name]) for name in ("loss", "psnr") if name in entry}
    tags |= {f"train/loss/{name}": float(value) for name, value in entry.get("losses", {}).items()}
    return tags


def require(logger: Logger) -> None:
    """Raise `LoggerUnavailable` now, before anything is written, if `logger` cannot be opened."""
    if logger == "tensorboard":
        _summary_writer()


def _summary_writer():
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError:  # torch's writer imports the tensorboard package
        raise LoggerUnavailable(
            "--logger tensorboard needs the tensorboard package: pip install 'nerfaug[tensorboard]'"
        ) from None
    return SummaryWriter


class TensorBoardLog:
    """A training callback (`CaptureSession.train(..., callback=log)`) that writes each entry's
    `scalars` at its step into `folder`; `close()` flushes the event file."""

    def __init__(self, folder: Path):
        self.folder = Path(folder)
        self.writer = _summary_writer()(log_dir=str(self.folder))

    def __call__(self, entry: Mapping) -> None:
        for tag, value in scalars(entry).items():
            self.writer.add_scalar(tag, value, int(entry["step"]))

    def close(self) -> None:
        self.writer.close()


def open_log(logger: Logger, run_folder: Path) -> Callable[[Mapping], None] | None:
    """The callback that logs a session's training in `run_folder`, or None for "none".

    Raises:
        LoggerUnavailable: "tensorboard" without the tensorboard package.
    """
    if logger == "none":
        return None
    return TensorBoardLog(runfiles.folder(run_folder, TENSORBOARD_FOLDER))
