"""The active-capture API under its earlier name: `from nerfaug.session import CaptureSession` keeps
working. The code lives in `nerfaug.capture`."""

from nerfaug.capture import (
    CHECKPOINT_FILE,
    DATASET_DIR,
    ENGINE_RADIUS,
    PROPOSALS_DIR,
    SESSION_FILE,
    SESSION_FORMAT,
    CaptureSession,
    Hemisphere,
    Proposal,
    SessionError,
    SessionState,
    estimate_centre,
    estimate_hemisphere,
    estimate_up,
    proposal_seed,
    read_poses,
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
