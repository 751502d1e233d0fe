"""The names of the built-in scenes (`nerfaug.scenes.builders` makes them), and the files some of
them are built from.

Its own module so that both the package (which re-exports it) and `render` can import it without
importing each other."""

from pathlib import Path

BUILTIN_SCENES = ("lego", "chair", "materials", "cow")

ASSETS = Path(__file__).with_name("assets")
"""Files shipped with the package that built-in scenes are built from, one folder per scene."""

BUILTIN_ASSETS = {"cow": ("cow.obj", "cow.mtl", "cow_texture.png")}
"""The files under `ASSETS / scene` each scene reads (their bytes change its pixels); the scenes
not listed are procedural. Each folder also holds the files' licence note (README.md)."""
