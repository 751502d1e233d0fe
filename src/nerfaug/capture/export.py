"""Writing a session's grown dataset for other tools, in any registered format, only into a new,
empty or earlier export folder (what `CaptureSession.export` does)."""

from __future__ import annotations

from pathlib import Path

from nerfaug import owned
from nerfaug.capture.runfolder import DATASET_SPLIT, EXPORT_KIND
from nerfaug.data.formats import FORMATS, find_split, has_split
from nerfaug.data.interface import DatasetSplit, Format
from nerfaug.errors import FolderRefused

# Held-out splits of the source dataset an export in a format with splits takes along.
HELD_OUT_SPLITS = ("val", "test")


def export(
    dataset: DatasetSplit,
    out: str | Path,
    fmt: Format,
    run_dir: Path,
    source_dir: Path,
    source_split: str,
    held_out: bool = True,
) -> Path:
    """Copy `dataset` into `out` in `fmt`; returns the new listing's path.

    Args:
        dataset: the session's grown dataset.
        fmt: the format to write.
        run_dir: the session's run folder (`out` must lie outside it).
        source_dir, source_split: the dataset folder and split the session started from (`out`
            must lie outside the folder).
        held_out: also copy the source folder's val and test splits (other than `source_split`),
            when `fmt` has splits.

    Raises:
        FolderRefused: `out` holds files nerfaug did not write, or overlaps the run folder or the source.
        ValueError: the cameras do not fit `fmt` (naming the formats that fit them).
        DatasetError: an image of the dataset is missing or unreadable (before anything is written).
    """
    out = Path(out)
    source_dir = Path(source_dir)
    if owned.overlaps(out, run_dir) or owned.overlaps(out, source_dir):
        raise FolderRefused(
            f"{out}: the export folder must lie outside the run folder {run_dir} and "
            f"the source dataset {source_dir}; choose another --out"
        )
    if not owned.is_empty(out) and not owned.marked(out, EXPORT_KIND):
        raise FolderRefused(
            f"{out}: not empty and not an earlier nerfaug export, so nothing is written "
            "there; choose a new or empty folder for --out"
        )
    dataset.frame_files()  # every image found before anything is written
    cameras = dataset.load(lazy=True).cameras
    if not fmt.fits(cameras):
        fitting = " or ".join(repr(f.name) for f in FORMATS.values() if f.fits(cameras))
        raise ValueError(
            f"these cameras do not fit the {fmt.name} format ({fmt.fits_rule}); export with format={fitting}"
        )
    owned.mark(out, EXPORT_KIND)
    path = fmt.copy(dataset, out, DATASET_SPLIT)
    # The source is the user's dataset folder (recorded at creation); its files are only read.
    if held_out and fmt.has_splits and source_dir.is_absolute() and source_dir.is_dir():
        for split in HELD_OUT_SPLITS:
            if split != source_split and has_split(source_dir, split):
                fmt.copy(find_split(source_dir, split), out, split)
    return path
