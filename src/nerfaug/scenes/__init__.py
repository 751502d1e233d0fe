"""Scenes: built-in procedural scenes and users' .blend files, rendered with Blender (bpy) into
NeRF-synthetic datasets.

bpy runs only in a child process (`nerfaug.scenes.worker`). This package imports neither bpy nor
torch when imported, so the child stays free of torch; the rendering functions load on first use.
"""

from nerfaug.scenes.builtin import BUILTIN_SCENES

_RENDER_NAMES = (
    "BlenderNotAvailable",
    "RenderError",
    "render_poses",
    "render_scene_dataset",
    "render_views",
)

__all__ = ["BUILTIN_SCENES", *_RENDER_NAMES]


def __getattr__(name: str):
    if name in _RENDER_NAMES:
        # Imported on first use: the bpy child process imports this package and must not load torch.
        from nerfaug.scenes import render

        return getattr(render, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
