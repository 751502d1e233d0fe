"""The work of the capture loop's commands (`nerfaug.cli.session`): propose, export, eval and
render-proposals. It loads torch (the session's NeRF, its dataset), so `nerfaug.cli.session`
imports it only when a command runs.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

from nerfaug.capture.evaluate import check_evaluation_out, trained_on_count, write_evaluation
from nerfaug.capture.folder import SessionFolder
from nerfaug.capture.proposal import check_poses_out, nearest_training_views
from nerfaug.capture.proposal_request import DEFAULT_MIN_SEPARATION, ProposalRequest
from nerfaug.capture.simulate import render_proposals as simulated_capture
from nerfaug.cli.option_names import as_options, checked
from nerfaug.cli.train_work import configure, open_session, warning_lines
from nerfaug.errors import DatasetError
from nerfaug.health import Health

# A proposed view closer than this to a training view (degrees about the hemisphere's centre) sees
# nearly the same image: the default --min-separation between two proposed views.
BESIDE_DEGREES = DEFAULT_MIN_SEPARATION


def propose(run: Path, request: ProposalRequest, out: Path, device: str, force: bool, threads: int) -> None:
    """`nerfaug propose`: the session's next views, written to `out` (and the map beside it)."""
    request = checked(request)  # before the session is opened: a refused call reads nothing
    check_poses_out(out, force)
    configure(threads)
    session = open_session(run, device, changing="propose")
    with warning_lines():
        proposal = session.propose(request)
    path = proposal.write(out)
    session.save()
    print(
        f"proposal {proposal.number} ({proposal.method}, model at step {proposal.step}): {path} (angles in "
        f"radians), map {path.with_suffix('.png')}"
    )
    trained = session.trainer.train_views
    nearest = nearest_training_views(proposal, trained.cameras, [Path(n).stem for n in trained.names])
    angles = zip(proposal.names, proposal.azimuth.tolist(), proposal.elevation.tolist(), nearest)
    for name, a, e, (near, angle) in angles:
        print(
            f"  {name}: azimuth {math.degrees(a):6.1f} deg, elevation {math.degrees(e):5.1f} deg (from the "
            f"horizon, + up); nearest training view {near}, {angle:.1f} deg away"
        )
    beside = [name for name, (_, angle) in zip(proposal.names, nearest) if angle < BESIDE_DEGREES]
    if beside:
        print(
            f"  {len(beside)} of {len(proposal)} views lie within {BESIDE_DEGREES:g} deg of a training view "
            f"({', '.join(beside)}): they add little new. The selection keeps proposed views apart from one "
            "another (--min-separation), not from the views trained on"
        )
    # The health check, with how the NeRF renders poses it never trained on (a report, not a refusal).
    print(Health.from_dict(session.state.proposals[-1].health).line())


def export(run: Path, out: Path, format: str) -> None:
    """`nerfaug export`: the session's grown dataset written to `out` in `format`."""
    folder = SessionFolder.open(run)  # exporting reads only the dataset folder
    path = folder.export(out, format)
    print(f"exported {folder.summary().views} views to {path}")


def _metric(value, digits: int) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def evaluate(
    run: Path, data: Path | None, split: str | None, out: Path | None, lpips: bool, device: str, threads: int
) -> None:
    """`nerfaug eval`: the session's NeRF scored on its held-out views: those its sparse start kept
    apart, or the split `split` of `data` (default: the dataset it started from), written to `out`."""
    configure(threads)
    session = open_session(run, device)
    if data is None:
        data = Path(session.state.source.data_dir)
        if not data.is_dir():  # e.g. a session made from uploaded images, whose folder was temporary
            raise DatasetError(data, f"the dataset {run} started from is gone; name one with --data")
    if out is not None:
        check_evaluation_out(out, data)
    views, chosen = session.test_views(data, split)
    split = split or session.default_test_split()
    if chosen.note is not None:
        print(f"note: {chosen.note}", file=sys.stderr)
    result = session.evaluate(views, lpips="auto" if lpips else None, progress=True)
    m = result.mean
    print(f"{run} (step {session.step}) on {chosen.says}: {len(views)} views")
    if chosen.names is not None:
        print(f"  views: {', '.join(views.names)}")
    print(f"  PSNR {_metric(m['psnr'], 2)} dB   SSIM {_metric(m['ssim'], 4)}   LPIPS {_metric(m['lpips'], 4)}")
    if m["lpips"] is None:
        print(f"  LPIPS {result.lpips_status}")
    if trained := trained_on_count(result):
        print(
            f"warning: {trained} of the {len(views)} views have the pose of a view the session trains on, so "
            "they score how well it was fitted, not held-out views",
            file=sys.stderr,
        )
    if out is not None:
        write_evaluation(out, result, run, session.step, data, split, chosen.says)
        print(f"  written to {out}")


def render_proposals(run: Path, poses: Path, scene: str, out: Path, samples: int, seed: int, threads: int) -> None:
    """`nerfaug render-proposals`: the proposed poses rendered with Blender into `out`."""
    with as_options():
        paths = simulated_capture(run, poses, scene, out, samples, seed, threads)
    print(f"rendered {len(paths)} views to {out}")
