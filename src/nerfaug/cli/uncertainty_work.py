"""The work of `nerfaug uncertainty`, whose options are in `nerfaug.cli.uncertainty`: a session's
uncertainty images written. This module loads torch: `nerfaug.cli.uncertainty` imports it only when
the command runs.
"""

from __future__ import annotations

from pathlib import Path

from nerfaug import owned
from nerfaug.capture.proposal import read_poses
from nerfaug.capture.session import CaptureSession
from nerfaug.capture.uncertainty_images import colour_scales, write_maps
from nerfaug.device import configure_process, resolve_device


def uncertainty(run: Path, poses: Path, out: Path, kind: str, device: str, threads: int, sizes: tuple, shared: bool):
    """`nerfaug uncertainty` (`nerfaug.cli.uncertainty.uncertainty`), its options checked: the maps of
    each pose in the poses JSON `poses`, at `sizes` (width, fisher, fisher_width), of the session
    in `run` (torch on `threads` threads), written into `out`, marked as a folder of the `kind`."""
    matrices, names = read_poses(poses)
    configure_process(threads=threads)
    session = CaptureSession.open(run, device=str(resolve_device(device)))
    maps = session.uncertainty_maps(matrices, *sizes, progress=True, names=names)
    owned.mark(out, kind)
    _write_uncertainty(out, names, maps, shared)


def _write_uncertainty(out: Path, names: list[str], maps: list, shared_scale: bool) -> None:
    """Each view's figure and arrays into `out`, one line each."""
    scales = colour_scales(maps) if shared_scale else None
    for name, view in zip(names, maps):
        write_maps(view, out, name, scales)
        print(f"{name}: mean entropy {view.entropy.mean():.3f} bits -> {out / (name + '.png')}")
    if scales is not None and len(maps) > 1:
        print(f"the {len(maps)} figures share their colour scales (--no-shared-scale: each its own)")
