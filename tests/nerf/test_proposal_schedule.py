"""nerfacto's proposal-update schedule: which steps train the proposal networks, checked against
an independent transcription of nerfstudio's rule, and what a skipped step leaves untouched."""

import numpy as np
import pytest

from nerfaug.nerf.config import NerfConfig
from nerfaug.nerf.proposal import ProposalSchedule
from nerfaug.nerf.trainer import Trainer


def nerfstudio_updates(n_steps: int, update_every: int, warmup: int) -> list[bool]:
    """nerfstudio's ProposalNetworkSampler: a counter of steps since the last update; update when
    it exceeds clip(interp(step, [0, warmup], [0, update_every]), 1, update_every), or below
    step 10."""
    since, out = 0, []
    for step in range(n_steps):
        since += 1
        interval = np.clip(np.interp(step, [0, warmup], [0, update_every]), 1, update_every)
        updated = since > interval or step < 10
        if updated:
            since = 0
        out.append(bool(updated))
    return out


@pytest.mark.parametrize("update_every, warmup", [(5, 5000), (3, 100), (1, 10)])
def test_schedule_equals_nerfstudios_rule(update_every, warmup):
    n = 6000 if warmup == 5000 else 400
    schedule = ProposalSchedule(update_every, warmup)
    ours = [schedule.updates(step) for step in range(n)]
    assert ours == nerfstudio_updates(n, update_every, warmup)
    if update_every > 1:  # late in training, one step in `update_every + 1` updates
        late = ours[warmup:]
        assert abs(sum(late) / len(late) - 1 / (update_every + 1)) < 0.01


def test_schedule_replays_after_a_reload_and_zero_means_every_step():
    sequential = ProposalSchedule(5, 50)
    expected = [sequential.updates(step) for step in range(200)]
    for start in (0, 17, 123):  # a resumed run asks from a later step first
        fresh = ProposalSchedule(5, 50)
        assert [fresh.updates(step) for step in range(start, 200)] == expected[start:]
    assert all(ProposalSchedule(0, 50).updates(step) for step in range(100))


def test_a_step_without_update_leaves_the_proposal_networks_untouched(sphere_views):
    views = sphere_views([0.0, 1.5, 3.0, 4.5], [0.8, 0.9, 1.0, 1.1], size=8)
    config = NerfConfig.preset(
        "nerfacto-cpu", batch_size=64, proposal_update_every=5, proposal_warmup_steps=10, render_chunk=1024
    )
    trainer = Trainer(views, config, seed=0, progress=False)
    proposal = trainer.model.sampler
    schedule_reference = nerfstudio_updates(40, 5, 10)
    for step in range(40):
        before = [p.detach().clone() for p in proposal.networks.parameters()]
        trainer.train_step()
        changed = any(not (p == b).all() for p, b in zip(proposal.networks.parameters(), before))
        assert changed == schedule_reference[step], step
