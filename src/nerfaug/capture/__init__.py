"""Active capture: a NeRF trained on the views you have proposes where to capture next, and grows
its dataset with what you captured there.

Rooms (the hemisphere and the engine frame are `nerfaug.data.world_frame`'s): `requests` (what a
session is asked, as typed schemas: settings, intrinsics, poses, ids; light), `proposal` (proposed
views, their JSON), `images` (captured images from any source, checked), `dataset` (what a session
reads of its dataset: the default split, frames as the trainer sees them, repeated poses; every
read and write on disk goes through the dataset's format, `nerfaug.data.formats`), `state`
(session.json as a typed model, and what a session reports), `runfolder` (the run folder's names,
and which folders may become one), `folder` (`SessionFolder`: a run folder read without its
model), `session` (`CaptureSession`: create, open, save, train; it coordinates), and the steps it
calls with the narrow pieces they need: `choose` (proposing the next views; what is asked,
`ProposalRequest` and `ViewConstraints`, is `proposal_request`, light), `constraints` (applying
where views may lie), `add` (adding captured views), `export` (writing the dataset in any
format), and, through `model` (`SessionModel`: the NeRF seen from the world frame),
`evaluate` and `uncertainty_images`; `simulate` (a simulated capture: proposed poses rendered by
Blender with the session's camera); `pool` (`SessionPool`: the sessions under one root, trained in
the background, their jobs resumed when the pool is made again: what `nerfaug serve` serves).
"""

import importlib

# Where each public name lives. They are imported on first use, so that the light rooms
# (`requests`: what `nerfaug train --help` reads) load without torch.
_HOMES = {
    "CHECKPOINT_FILE": "runfolder",
    "DATASET_DIR": "runfolder",
    "PROPOSALS_DIR": "runfolder",
    "SESSION_FILE": "runfolder",
    "SESSION_FORMAT": "state",
    "SessionError": "state",
    "SessionState": "state",
    "CaptureSession": "session",
    "SessionFolder": "folder",
    "Proposal": "proposal",
    "proposal_seed": "proposal",
    "read_poses": "proposal",
    "ProposalRequest": "proposal_request",
    "ViewConstraints": "proposal_request",
    "Intrinsics": "requests",
    "SessionSettings": "requests",
    "ENGINE_RADIUS": "nerfaug.data.world_frame",
    "Hemisphere": "nerfaug.data.world_frame",
    "estimate_centre": "nerfaug.data.world_frame",
    "estimate_hemisphere": "nerfaug.data.world_frame",
    "estimate_up": "nerfaug.data.world_frame",
}
__all__ = sorted(_HOMES)


def __getattr__(name: str):
    home = _HOMES.get(name)
    if home is None:
        raise AttributeError(f"module 'nerfaug.capture' has no attribute {name!r}")
    module = importlib.import_module(home if "." in home else f"nerfaug.capture.{home}")
    return getattr(module, name)
