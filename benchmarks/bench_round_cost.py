"""What one round of the study of rounds costs, per method, against the training between two rounds
(BENCHMARKS.md, "A round's scoring against its training"): at the study's settings
(docs/study-plan.md, plan of 2026-11-28: `nerfacto-cpu`, 100 px, 4 initial views of layout 0, one
view a round every 100 steps from step 200), one NeRF is trained to step 200 on a scene, then each
method scores the pool and chooses one view with that same model (the first round's choice), and
the next 100 steps of training are timed. One thread, as a study run; each part is timed in CPU
seconds of this process (on one thread, its work, whatever else the machine runs) and in wall
seconds.

    python benchmarks/bench_round_cost.py /work/data/lego100 --json round-cost.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

METHODS = ("uniform", "ours", "ours-batch-sharp", "fisherrf", "entropy-sampling", "furthest")


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("scene", type=Path, help="a dataset folder (e.g. the built-in lego rendered at 100 px)")
    p.add_argument("--methods", nargs="+", default=list(METHODS))
    p.add_argument("--json", type=Path)
    args = p.parse_args(argv)

    import torch

    from nerfaug.device import configure_process
    from nerfaug.experiment.config import STUDY_PRESETS
    from nerfaug.experiment.protocol import load_scene_data
    from nerfaug.nerf.trainer import Trainer
    from nerfaug.selection import select_views

    configure_process(threads=1)
    config = STUDY_PRESETS.choose(
        "study",
        engine="nerfacto-cpu",
        resolution=100,
        n_initial=4,
        n_new=1,
        add_at_step=200,
        rounds=8,
        round_every=100,
        layouts=3,
        device="cpu",
    )
    data = load_scene_data(args.scene, config, layout=0)
    trainer = Trainer(data.initial, config.engine_config(args.scene.name), seed=0, device="cpu", progress=False)
    begin, cpu = time.perf_counter(), time.process_time()
    trainer.train(config.add_at_step)
    first = {"wall_s": time.perf_counter() - begin, "cpu_s": time.process_time() - cpu}
    print(f"trained to step {config.add_at_step}: {first['cpu_s']:.1f} CPU s", flush=True)
    scoring = {}
    for method in args.methods:
        begin, cpu = time.perf_counter(), time.process_time()
        selection = select_views(
            method,
            trainer.model,
            trainer.train_views.cameras,
            data.pool.cameras,
            config.n_new,
            torch.Generator().manual_seed(0),
            config.selection,
        )
        scoring[method] = {
            "wall_s": time.perf_counter() - begin,
            "cpu_s": time.process_time() - cpu,
            "chosen": [int(i) for i in selection.indices],
        }
        print(f"{method}: {scoring[method]['cpu_s']:.2f} CPU s, chose {scoring[method]['chosen']}", flush=True)
    trainer.add_views(data.pool.subset(scoring[args.methods[0]]["chosen"]))
    begin, cpu = time.perf_counter(), time.process_time()
    trainer.train(config.add_at_step + config.round_every)
    between = {"wall_s": time.perf_counter() - begin, "cpu_s": time.process_time() - cpu}
    print(f"a round's training ({config.round_every} steps): {between['cpu_s']:.1f} CPU s", flush=True)
    result = {
        "scene": str(args.scene),
        "settings": {
            "engine": config.engine.record(),
            "resolution": config.resolution,
            "n_initial": config.n_initial,
            "pool": len(data.pool),
            "round_every": config.round_every,
        },
        "train_to_first_round_s": first,
        "train_between_rounds_s": between,
        "scoring": scoring,
        "scoring_share_of_round_cpu": {m: s["cpu_s"] / (s["cpu_s"] + between["cpu_s"]) for m, s in scoring.items()},
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count(), "load": os.getloadavg()},
        "torch": torch.__version__,
    }
    print(json.dumps(result, indent=1))
    if args.json:
        args.json.write_text(json.dumps(result, indent=1) + "\n")
    return result


if __name__ == "__main__":
    main()
