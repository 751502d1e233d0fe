"""nerfaug: choose which camera views to add when a NeRF has too little data.

Data flows one way through the package:
scene -> data (images + cameras) -> nerf (field, renderer, trainer) -> uncertainty (scores per
candidate view) -> selection (chosen views) -> oracle (renders them) -> trainer continues ->
evaluation -> statistics -> report.

Conventions, stated once: cameras are OpenGL-style (the camera looks down its -z axis, +y is up),
poses are 4x4 camera-to-world matrices, the world is z-up, angles are in radians, images are
float32 in [0, 1] with shape (H, W, 3) (HWC).
"""

__version__ = "0.1.0"
