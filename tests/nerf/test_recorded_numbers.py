"""The nerfacto-cpu engine's numbers, recorded before its CPU speed work: a faster path must
compute the same losses and renders (training amplifies any difference, however small: a change
of one bit in one weight moved the losses of a 100 px lego run by 2e-5 after 340 steps and 6e-4
after 450, so only the same arithmetic keeps a whole run's losses within 1e-5)."""

import pytest

from nerfaug.nerf import hash_cpu
from nerfaug.nerf.config import NerfConfig
from nerfaug.nerf.encoding import HashEncoding

# Recorded with the engine of commit e2511ee on an AMD EPYC (AVX2) CPU, torch 2.13.0, one
# thread: `Trainer(views, preset, seed=3)` on the 4 sphere views, the loss of each of 12 steps,
# then the sums of `render_weights_only` and `render_rays(...).rgb` over two rays.
RECORDED = {
    "nerfacto-cpu": [
        "0x1.8aa4480000000p-4",
        "0x1.6ae4ee0000000p-4",
        "0x1.55124e0000000p-4",
        "0x1.6668f20000000p-4",
        "0x1.7357a60000000p-4",
        "0x1.4b99380000000p-4",
        "0x1.5fdb4e0000000p-4",
        "0x1.5549960000000p-4",
        "0x1.5643120000000p-4",
        "0x1.4777480000000p-4",
        "0x1.42359c0000000p-4",
        "0x1.22cf8c0000000p-4",
        "0x1.4760c00000000p-3",
        "0x1.6355000000000p+2",
    ],
    "nerfacto-cpu-last-sample": [
        "0x1.756d2e0000000p-3",
        "0x1.5f388e0000000p-3",
        "0x1.43e8da0000000p-3",
        "0x1.2834480000000p-3",
        "0x1.0169b20000000p-3",
        "0x1.a4ee180000000p-4",
        "0x1.3f29f20000000p-4",
        "0x1.0d6a620000000p-4",
        "0x1.22bcfc0000000p-4",
        "0x1.3415920000000p-4",
        "0x1.48f9060000000p-4",
        "0x1.3568a80000000p-4",
        "0x1.52f3a20000000p-5",
        "0x1.7492c00000000p+2",
    ],
}


@pytest.mark.rounding
@pytest.mark.parametrize("preset", list(RECORDED))
@pytest.mark.parametrize("kernel", ["torch", "cpu"])
def test_nerfacto_cpu_computes_the_numbers_recorded_before_its_speed_work(preset, kernel, engine_numbers, monkeypatch):
    """The reference path, and the fused CPU loop (`nerfaug.nerf.hash_cpu`: the same features,
    gradients summed in another order) over these 12 steps too."""
    if kernel == "cpu" and not hash_cpu.available():
        pytest.skip("no C compiler built the fused CPU loop")
    monkeypatch.setattr(HashEncoding, "default_kernel", kernel)
    got, _ = engine_numbers(NerfConfig.preset(preset), 12)
    # 1e-5 as the engine's other recorded numbers: CPUs with other vector units round differently.
    assert got == pytest.approx([float.fromhex(x) for x in RECORDED[preset]], rel=1e-5)
