"""Where a study run's time goes besides training, on the CPU, side by side (BENCHMARKS.md, "Cheaper
trials"): a trial batch of two runs of a small batched engine on the toy sphere scene, profiled by
the parts of a run (selection, evaluation, the figures and files a run writes, the health check,
the uncertainty images the study leaves out); then the test views of one trained run rendered one
at a time (as a run evaluates them) against several views' rays in one pass, with the largest
difference between the two renders.

    python benchmarks/bench_trial_costs.py --json costs.json
"""

from __future__ import annotations

import argparse
import cProfile
import json
import pstats
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

PARTS = {  # a function of the run's code -> what it is
    "run_trials": "the whole batch",
    "train": "training (both runs)",
    "select_views": "selection",
    "evaluate_views": "evaluation (test views rendered and scored)",
    "_save_view": "saved test renders (PNG)",
    "plot_hemisphere_map": "the hemisphere map figure",
    "model_health": "the health check",
    "save_view_uncertainty": "uncertainty images (off in study runs)",
}


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--resolution", type=int, default=24)
    p.add_argument("--steps", type=int, default=200)
    p.add_argument("--views-per-pass", type=int, default=4)
    p.add_argument("--json", type=Path)
    args = p.parse_args(argv)

    import torch

    import gpu_study
    from nerfaug.cameras import image_rays
    from nerfaug.device import configure_process
    from nerfaug.experiment.config import PROTOCOL_PRESETS
    from nerfaug.experiment.protocol import load_scene_data, run_trials
    from nerfaug.experiment.store import RunKey
    from nerfaug.nerf.trainer import Trainer

    configure_process(threads=1)
    work = Path(tempfile.mkdtemp())
    gpu_study.toy(work / "sphere", work / "packs")
    config = PROTOCOL_PRESETS.choose(
        "tiny",
        engine="nerfacto-cpu+batch_size=64+num_samples=8+proposal_samples=16,8",
        resolution=args.resolution,
        steps=args.steps,
        n_test=4,
        batch=2,
        view_uncertainty=True,
        scenes=(str(work / "sphere"),),
    )
    keys = [RunKey("sphere", "uniform", 0), RunKey("sphere", "ours", 0)]
    profile = cProfile.Profile()
    profile.enable()
    run_trials(keys, {"sphere": work / "sphere"}, config, work / "runs")
    profile.disable()
    stats = pstats.Stats(profile).stats
    parts = {}
    for (_, _, name), (_, _, _, cumulative, _) in stats.items():
        if name in PARTS:
            parts[PARTS[name]] = max(parts.get(PARTS[name], 0.0), cumulative)

    # Test views one at a time against several per pass, on one trained run.
    data = load_scene_data(work / "sphere", config)
    trainer = Trainer(data.initial, config.engine_config("sphere"), 0, "cpu", progress=False)
    trainer.train(args.steps)
    model, cameras = trainer.model, data.test.cameras
    with torch.no_grad():
        start = time.perf_counter()
        alone = [model.render_image(cameras, i)["rgb"] for i in range(len(cameras))]
        one_at_a_time = time.perf_counter() - start
        start = time.perf_counter()
        together = []
        for first in range(0, len(cameras), args.views_per_pass):
            views = range(first, min(len(cameras), first + args.views_per_pass))
            rays = [image_rays(cameras, i) for i in views]
            rgb = model.render_rays(torch.cat([o for o, _ in rays]), torch.cat([d for _, d in rays])).rgb
            together += list(rgb.reshape(len(views), cameras.height, cameras.width, 3))
        per_pass = time.perf_counter() - start
    found = {
        "machine": {"torch": torch.__version__, "threads": torch.get_num_threads()},
        "settings": vars(args) | {"json": str(args.json)},
        "parts_s": parts,
        "test_views": {
            "views": len(cameras),
            "one_at_a_time_s": one_at_a_time,
            f"{args.views_per_pass}_per_pass_s": per_pass,
            "max_abs_difference": max(float((a - b).abs().max()) for a, b in zip(alone, together, strict=True)),
        },
    }
    print(json.dumps(found, indent=2))
    if args.json:
        args.json.write_text(json.dumps(found, indent=2))
    return found


if __name__ == "__main__":
    main()
