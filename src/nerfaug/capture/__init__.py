"""Active capture: a NeRF trained on the views you have proposes where to capture next, and grows
its dataset with what you captured there.

Rooms (the hemisphere and the engine frame are `nerfaug.data.frame`'s): `proposal` (proposed views, their JSON),
`images` (captured images from any source, checked), `dataset` (what a session reads of its
dataset: the default split, frames as the trainer sees them, repeated poses; every read and write
on disk goes through the dataset's format, `nerfaug.data.formats`), `state` (session.json, typed,
and the run folder's names), `runfolder` (which folders may become a run folder), `session`
(`CaptureSession`: create, open, save, train; it coordinates), and the steps it calls with the
narrow pieces they need: `choose` (proposing the next views, `ProposalRequest`), `add` (adding
captured views), `export` (writing the dataset in any format), and, through `model`
(`SessionModel`: the NeRF seen from the world frame), `evaluate` and `uncertainty_images`.
"""

from nerfaug.capture.proposal import Proposal, proposal_seed, read_poses
from nerfaug.capture.session import CaptureSession
from nerfaug.capture.state import (
    CHECKPOINT_FILE,
    DATASET_DIR,
    PROPOSALS_DIR,
    SESSION_FILE,
    SESSION_FORMAT,
    SessionError,
    SessionState,
)
from nerfaug.data.frame import (
    ENGINE_RADIUS,
    Hemisphere,
    estimate_centre,
    estimate_hemisphere,
    estimate_up,
)

__all__ = [
    "CHECKPOINT_FILE",
    "DATASET_DIR",
    "ENGINE_RADIUS",
    "PROPOSALS_DIR",
    "SESSION_FILE",
    "SESSION_FORMAT",
    "CaptureSession",
    "Hemisphere",
    "Proposal",
    "SessionError",
    "SessionState",
    "estimate_centre",
    "estimate_hemisphere",
    "estimate_up",
    "proposal_seed",
    "read_poses",
]
