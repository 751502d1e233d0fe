"""The `nerfaug scene` commands: render a built-in scene or a .blend file as a dataset (`render`),
and ready a downloaded dataset for the experiments (`prepare`). Their work (which loads torch) is
imported when one runs, so that `nerfaug scene ... --help` answers at once."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import tyro

Positional = tyro.conf.Positional


def scene_render(
    scene: Annotated[str, Positional, tyro.conf.arg(metavar="SCENE")],
    out: Path,
    res: int = 200,
    pool: int = 300,
    test: int = 200,
    initial: int = 6,
    samples: int = 16,
    seed: int = 0,
) -> None:
    """Render a built-in scene (lego, chair, materials, cow) or a .blend file as a Blender-format dataset.

    Writes transforms_train.json (the candidate pool, uniform on the hemisphere),
    transforms_initial.json (fixed views on one half), transforms_test.json and transforms_val.json.
    Cached: the same arguments render nothing the second time.

    Args:
        scene: a built-in scene name or a path to a .blend file.
        out: the dataset folder to write.
        res: image width and height in pixels.
        pool: candidate views, uniform over the hemisphere.
        test: test views, spread over the hemisphere.
        initial: initial training views, all on one half of the hemisphere.
        samples: Cycles samples per pixel.
        seed: seeds the pool's poses and Cycles' noise.
    """
    from nerfaug.scenes import render_scene_dataset  # torch: here, so that --help loads none

    path = render_scene_dataset(
        scene, out, resolution=res, pool=pool, test=test, initial=initial, samples=samples, seed=seed, progress=True
    )
    print(f"dataset written to {path}")


def scene_prepare(
    source: Annotated[Path, Positional, tyro.conf.arg(metavar="SOURCE")],
    out: Path,
    width: int = 100,
) -> None:
    """Prepare a downloaded dataset for `nerfaug run` and `nerfaug study`: a copy with images
    WIDTH px across and masks merged into their alpha.

    SOURCE may be a NeRF-synthetic folder (transforms_{train,val,test}.json), an LLFF capture
    (poses_bounds.npy, images/, optional masks/), a DTU scan in the IDR/NeuS layout
    (cameras_sphere.npz, image/ or images/, mask/) or a nerfstudio folder. A capture without a
    test split is written as one transforms.json; the experiments keep test views apart from it,
    spread over all directions. prepared.json records the source's digest. Running it again with
    the same source and width does nothing.

    Args:
        source: the downloaded dataset folder (it is only read).
        out: the folder to write (new or empty).
        width: image width in pixels (any size up to the source's; area-averaged).
    """
    from nerfaug.data.prepare import PREPARED, prepare_dataset  # torch: here, so that --help loads none
    from nerfaug.jsonio import read_json
    from nerfaug.layouts import HELD_OUT_SHARE

    path = prepare_dataset(source, out, width)
    print(f"dataset prepared in {path}")
    record = read_json(path / PREPARED)
    views = record["splits"]["train"]
    if record["captured"] and views < HELD_OUT_SHARE:  # prepared all the same: train may give the centre
        print(
            f"warning: {source}: {views} view{'s' * (views != 1)}; `nerfaug run` and `study` need at least "
            f"{HELD_OUT_SHARE}, and `nerfaug train` at least 2 to estimate the centre (or --centre and "
            "--radius): capture more views",
            file=sys.stderr,
        )


def scene() -> None:
    """Scenes: `nerfaug scene render SCENE --out DIR` renders a built-in scene (lego, chair,
    materials, cow) or a .blend file as a Blender-format dataset; `nerfaug scene prepare SOURCE
    --out DIR` readies a downloaded dataset (NeRF-synthetic, LLFF, DTU) for experiments (`--help`
    of each)."""
    tyro.extras.subcommand_cli_from_dict(COMMANDS, args=["--help"], prog="nerfaug scene")


COMMANDS = {"render": scene_render, "prepare": scene_prepare}
"""The subcommands of `nerfaug scene` by name."""
