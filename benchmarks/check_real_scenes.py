"""How each prepared real scene divides into test, initial and candidate views, as the study runs
it: the views per split, how far round the object the test views reach (the span of their
azimuths about the scene's up axis: 360 less the widest gap), and the source's digest.

    python benchmarks/check_real_scenes.py data/real/mic data/real/maryRose ... [--layouts 3]

Prints a Markdown table (recorded in docs/real-scenes.md). A test subset that covers only one
side of the object spans under 180 degrees; every scene here should span over 300.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from nerfaug.experiment.config import ExperimentConfig
from nerfaug.experiment.protocol import load_scene_data
from nerfaug.hemisphere import angles_from_pose


def span_deg(camera_to_world) -> float:
    """360 degrees less the widest gap between the views' azimuths about +z."""
    azimuth = np.sort(np.degrees(angles_from_pose(camera_to_world)[0].numpy()) % 360)
    gaps = np.diff(np.concatenate([azimuth, azimuth[:1] + 360]))
    return float(360 - gaps.max())


def describe(folder: Path, config: ExperimentConfig) -> list[str]:
    prepared = json.loads((folder / "prepared.json").read_text()) if (folder / "prepared.json").is_file() else {}
    layouts = [load_scene_data(folder, config, layout=k) for k in range(config.layouts)]
    first = layouts[0]
    halves = ", ".join(
        f"{d.record['half']['start_deg']:.0f}+{d.record['half']['width_deg']:.0f}"
        for d in layouts
        if "half" in d.record
    )
    return [
        folder.name,
        prepared.get("format", "?"),
        f"{first.test.cameras.width}x{first.test.cameras.height}",
        str(len(first.initial) + len(first.pool)),
        f"{len(first.test)} ({first.record['test_rule']})",
        f"{span_deg(first.test.cameras.camera_to_world):.0f}",
        str(len(first.pool)),
        halves,
        f"`{prepared.get('source_digest', '?')[:16]}`",
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folders", nargs="+", type=Path)
    parser.add_argument("--layouts", type=int, default=3)
    parser.add_argument("--n-test", type=int, default=50)
    args = parser.parse_args()
    config = ExperimentConfig(resolution=100, n_test=args.n_test, layouts=args.layouts)
    headers = ["scene", "format", "size", "initial + pool", "test views", "test span (deg)", "pool"]
    headers += ["initial halves (start+width deg)", "source sha256"]
    print("| " + " | ".join(headers) + " |")
    print("|" + "---|" * len(headers))
    for folder in args.folders:
        print("| " + " | ".join(describe(folder, config)) + " |", flush=True)
    print(f"\nn_test {args.n_test}, {args.layouts} layouts; azimuths about each scene's up axis.")


if __name__ == "__main__":
    main()
