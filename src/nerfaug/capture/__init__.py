"""Active capture: a NeRF trained on the views you have proposes where to capture next, and grows
its dataset with what you captured there.

Rooms: `frame` (the hemisphere and the engine frame), `proposal` (proposed views, their JSON),
`images` (captured images from any source, checked), `dataset` (the run's dataset folder and the
one frame-copying helper), `state` (session.json, typed, and the run folder's names), `session`
(`CaptureSession`: create, open, save, train), and what its methods do: `choose` (proposing the
next views), `add` (adding captured views), `export` (writing the dataset for other tools).
"""

from nerfaug.capture.frame import (
    ENGINE_RADIUS,
    Hemisphere,
    estimate_centre,
    estimate_hemisphere,
    estimate_up,
)
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
