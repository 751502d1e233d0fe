"""The built-in scenes, built procedurally in Blender (bpy), and the render settings they share.

Imported only inside the render child process (`nerfaug.scenes.worker`), because it imports bpy.
World z-up; every scene is centred at the origin and scaled to fit inside [-1.1, 1.1]^3, like
the NeRF-synthetic objects, so cameras on the radius-4.03 hemisphere frame it.

Each scene echoes what makes its paper counterpart hard:
- `lego`: a bulldozer of many small parts (treads with cleats, wheels, studs, pistons, a blade);
- `chair`: thin tapered legs and stretchers, a slatted back;
- `materials`: orbs of diffuse, glossy, metallic, glass-like and textured materials on a base,
  reflecting a graded sky, so their colour depends on the viewing direction;
- `cow`: not procedural but a scanned-looking organic shape, Keenan Crane's "spot" cow (public
  domain, `assets/cow/`): one smooth closed mesh whose detail is in its image texture, not its
  geometry.
"""

from __future__ import annotations

import math
from pathlib import Path

# isort: off
import bpy  # first: importing bpy is what makes bmesh and mathutils importable
import bmesh
from mathutils import Matrix, Vector

# isort: on
from nerfaug.scenes.builtin import ASSETS

RGB = tuple[float, float, float]
HALF_EXTENT = 1.1


# ---- materials ---------------------------------------------------------------------------------


def principled(
    name: str,
    colour: RGB,
    roughness: float = 0.5,
    metallic: float = 0.0,
    transmission: float = 0.0,
    coat: float = 0.0,
    ior: float = 1.45,
) -> bpy.types.Material:
    """A Principled BSDF material with a flat base colour (linear RGB in [0, 1])."""
    material = bpy.data.materials.new(name)
    bsdf = material.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (*colour, 1.0)
    bsdf.inputs["Roughness"].default_value = roughness
    bsdf.inputs["Metallic"].default_value = metallic
    bsdf.inputs["Transmission Weight"].default_value = transmission
    bsdf.inputs["Coat Weight"].default_value = coat
    bsdf.inputs["IOR"].default_value = ior
    return material


def patterned(
    name: str,
    colour_a: RGB,
    colour_b: RGB,
    pattern: str = "checker",
    scale: float = 8.0,
    roughness: float = 0.6,
) -> bpy.types.Material:
    """A diffuse-ish material whose colour varies between two colours over the surface.

    `pattern` is "checker", "noise" or "wave" (wood grain). The pattern follows the object's own
    coordinates, so it stays fixed to the part when seen from any view (a NeRF can learn it).
    """
    material = principled(name, colour_a, roughness)
    nodes, links = material.node_tree.nodes, material.node_tree.links
    coords = nodes.new("ShaderNodeTexCoord")
    texture = nodes.new(
        {"checker": "ShaderNodeTexChecker", "noise": "ShaderNodeTexNoise", "wave": "ShaderNodeTexWave"}[pattern]
    )
    texture.inputs["Scale"].default_value = scale
    if pattern == "wave":
        texture.inputs["Distortion"].default_value = 4.0
    ramp = nodes.new("ShaderNodeValToRGB")
    ramp.color_ramp.elements[0].color = (*colour_a, 1.0)
    ramp.color_ramp.elements[1].color = (*colour_b, 1.0)
    links.new(coords.outputs["Object"], texture.inputs["Vector"])
    links.new(texture.outputs["Fac"], ramp.inputs["Fac"])
    links.new(ramp.outputs["Color"], nodes["Principled BSDF"].inputs["Base Color"])
    return material


# ---- meshes ------------------------------------------------------------------------------------


def mesh_object(
    name: str, bm: bmesh.types.BMesh, material, location=(0, 0, 0), rotation=(0, 0, 0), smooth: bool = False
) -> bpy.types.Object:
    """Link a new object holding the mesh in `bm` (which is freed) to the scene."""
    for face in bm.faces:
        face.smooth = smooth
    mesh = bpy.data.meshes.new(name)
    bm.to_mesh(mesh)
    bm.free()
    mesh.materials.append(material)
    obj = bpy.data.objects.new(name, mesh)
    obj.location, obj.rotation_euler = location, rotation
    bpy.context.scene.collection.objects.link(obj)
    return obj


def box(name: str, size, location, material, rotation=(0, 0, 0)) -> bpy.types.Object:
    """An axis-aligned box of `size` (x, y, z) centred at `location`, then rotated (XYZ Euler)."""
    bm = bmesh.new()
    bmesh.ops.create_cube(bm, size=1.0, matrix=Matrix.Diagonal((*size, 1.0)))
    return mesh_object(name, bm, material, location, rotation)


def cylinder(
    name: str,
    radius: float,
    depth: float,
    location,
    material,
    rotation=(0, 0, 0),
    top_radius: float | None = None,
    segments: int = 20,
) -> bpy.types.Object:
    """A capped cylinder (a cone frustum if `top_radius` differs) along its local z axis."""
    bm = bmesh.new()
    bmesh.ops.create_cone(
        bm,
        cap_ends=True,
        segments=segments,
        radius1=radius,
        radius2=radius if top_radius is None else top_radius,
        depth=depth,
    )
    return mesh_object(name, bm, material, location, rotation, smooth=True)


def rod(name: str, start, end, radius: float, material, end_radius: float | None = None) -> bpy.types.Object:
    """A cylinder from point `start` to point `end` (world space)."""
    start, end = Vector(start), Vector(end)
    axis = end - start
    rotation = axis.to_track_quat("Z", "Y").to_euler()
    return cylinder(
        name, radius, axis.length, (start + end) / 2, material, rotation, top_radius=end_radius, segments=12
    )


def sphere(name: str, radius: float, location, material) -> bpy.types.Object:
    """A smooth UV sphere."""
    bm = bmesh.new()
    bmesh.ops.create_uvsphere(bm, u_segments=32, v_segments=16, radius=radius)
    return mesh_object(name, bm, material, location, smooth=True)


def fit_to_box(half_extent: float = HALF_EXTENT) -> None:
    """Move and scale every object so their joint bounding box is centred at the origin with its
    largest half-side equal to `half_extent`. Objects must be unparented."""
    bpy.context.view_layer.update()
    corners = [
        obj.matrix_world @ Vector(c) for obj in bpy.context.scene.objects if obj.type == "MESH" for c in obj.bound_box
    ]
    low = Vector([min(c[k] for c in corners) for k in range(3)])
    high = Vector([max(c[k] for c in corners) for k in range(3)])
    centre, scale = (low + high) / 2, half_extent / (max(high - low) / 2)
    for obj in bpy.context.scene.objects:
        obj.location = (obj.location - centre) * scale
        obj.scale = obj.scale * scale


# ---- scenes ------------------------------------------------------------------------------------


def build_lego() -> None:
    """A yellow bulldozer (front towards +x): treads with cleats and wheels, chassis, hood with
    studs and an exhaust, a cab with windows, push arms, hydraulic pistons and a curved blade."""
    yellow = patterned("yellow", (0.85, 0.55, 0.02), (0.75, 0.45, 0.01), "noise", 12.0, 0.4)
    tread = principled("tread", (0.03, 0.03, 0.035), 0.8)
    cleat = principled("cleat", (0.12, 0.12, 0.13), 0.6)
    steel = principled("steel", (0.6, 0.6, 0.62), 0.3, metallic=1.0)
    red = principled("red", (0.6, 0.03, 0.02), 0.4)
    window = principled("window", (0.02, 0.08, 0.2), 0.05, coat=1.0)
    grey = principled("grey", (0.25, 0.25, 0.27), 0.5)
    orange = principled("orange", (1.0, 0.25, 0.0), 0.3)

    for side in (-1, 1):
        y = 0.5 * side
        box(f"track{side}", (1.14, 0.26, 0.36), (0, y, 0.18), tread)
        for x in (-0.57, 0.57):
            cylinder(f"track_end{side}{x}", 0.18, 0.26, (x, y, 0.18), tread, (math.pi / 2, 0, 0))
            cylinder(f"sprocket{side}{x}", 0.14, 0.03, (x, y + 0.145 * side, 0.18), red, (math.pi / 2, 0, 0))
        for k in range(10):
            box(f"cleat{side}_{k}", (0.06, 0.28, 0.03), (-0.54 + 0.12 * k, y, 0.375), cleat)
        for x in (-0.3, -0.1, 0.1, 0.3):
            cylinder(f"wheel{side}{x}", 0.09, 0.03, (x, y + 0.145 * side, 0.16), steel, (math.pi / 2, 0, 0))
        box(f"push_arm{side}", (0.62, 0.06, 0.08), (0.6, 0.66 * side, 0.22), yellow)
        rod(f"barrel{side}", (0.35, 0.36 * side, 0.62), (0.62, 0.36 * side, 0.52), 0.04, grey)
        rod(f"piston{side}", (0.6, 0.36 * side, 0.53), (0.9, 0.36 * side, 0.42), 0.022, steel)

    box("chassis", (1.3, 0.74, 0.3), (-0.05, 0, 0.27), yellow)
    box("hood", (0.6, 0.6, 0.28), (0.3, 0, 0.56), yellow)
    box("grille", (0.02, 0.5, 0.2), (0.605, 0, 0.56), grey)
    for i in range(4):
        for j in range(2):
            cylinder(f"stud{i}{j}", 0.05, 0.04, (0.09 + 0.14 * i, -0.1 + 0.2 * j, 0.72), yellow)
    cylinder("exhaust", 0.035, 0.4, (0.42, 0.2, 0.85), grey)
    cylinder("exhaust_cap", 0.045, 0.03, (0.42, 0.2, 1.06), tread)

    box("cab_glass", (0.5, 0.56, 0.46), (-0.3, 0, 0.67), window)
    box("roof", (0.62, 0.66, 0.08), (-0.3, 0, 0.94), yellow)
    for x in (-0.58, -0.02):
        for y in (-0.3, 0.3):
            box(f"pillar{x}{y}", (0.05, 0.05, 0.48), (x, y, 0.68), yellow)
    for y in (-0.2, 0.2):
        cylinder(f"beacon{y}", 0.04, 0.06, (-0.05, y, 1.0), orange)
    box("counterweight", (0.14, 0.56, 0.22), (-0.76, 0, 0.3), grey)
    box("ripper", (0.05, 0.06, 0.3), (-0.86, 0, 0.14), steel, (0, -0.4, 0))

    # Three slabs make a blade that is concave towards the front: the outer ones lean out.
    for k, (x, z, tilt) in enumerate([(1.0, 0.1, -0.35), (0.95, 0.27, 0.0), (1.0, 0.44, 0.35)]):
        box(f"blade{k}", (0.05, 1.4, 0.18), (x, 0, z), yellow, (0, tilt, 0))
    box("blade_edge", (0.06, 1.4, 0.04), (1.01, 0, 0.0), steel)
    fit_to_box()


def build_chair() -> None:
    """A wooden chair: thin tapered legs with stretchers, a seat with a patterned cushion, and a
    back of two posts, two rails and five thin slats."""
    walnut = patterned("walnut", (0.12, 0.05, 0.02), (0.25, 0.12, 0.05), "wave", 6.0, 0.45)
    oak = patterned("oak", (0.55, 0.33, 0.13), (0.38, 0.2, 0.07), "wave", 5.0, 0.5)
    cushion = patterned("cushion", (0.6, 0.04, 0.05), (0.9, 0.6, 0.1), "checker", 10.0, 0.9)
    cream = principled("cream", (0.85, 0.8, 0.65), 0.35)

    corners = [(x, y) for x in (-0.42, 0.42) for y in (-0.42, 0.42)]
    for x, y in corners:
        cylinder(f"leg{x}{y}", 0.022, 0.9, (x, y, 0.45), walnut, top_radius=0.04)
    for y in (-0.42, 0.42):
        rod(f"side_stretcher{y}", (-0.42, y, 0.3), (0.42, y, 0.3), 0.014, walnut)
    rod("cross_stretcher", (0, -0.42, 0.22), (0, 0.42, 0.22), 0.014, walnut)

    box("seat", (1.0, 1.0, 0.08), (0, 0, 0.94), oak)
    box("cushion", (0.86, 0.86, 0.08), (0.02, 0, 1.02), cushion)

    back_x = -0.44
    for y in (-0.42, 0.42):
        cylinder(f"post{y}", 0.035, 1.15, (back_x, y, 1.55), walnut, top_radius=0.03)
    box("mid_rail", (0.05, 0.88, 0.07), (back_x, 0, 1.3), oak)
    box("top_rail", (0.07, 0.98, 0.14), (back_x, 0, 2.07), oak)
    for k in range(5):
        box(f"slat{k}", (0.025, 0.06, 0.7), (back_x, -0.28 + 0.14 * k, 1.68), cream)
    fit_to_box()


def build_materials() -> None:
    """Eight orbs of different materials on pedestals on a checkered base."""
    base = patterned("base", (0.32, 0.34, 0.38), (0.18, 0.19, 0.22), "checker", 6.0, 0.6)
    pedestal = principled("pedestal", (0.05, 0.05, 0.05), 0.4)
    orbs = [
        principled("diffuse_red", (0.8, 0.08, 0.06), 1.0),
        principled("glossy_green", (0.05, 0.55, 0.15), 0.05, coat=1.0),
        principled("gold", (1.0, 0.77, 0.34), 0.15, metallic=1.0),
        principled("chrome", (0.92, 0.92, 0.95), 0.02, metallic=1.0),
        principled("glass", (0.9, 0.97, 1.0), 0.0, transmission=1.0, ior=1.45),
        principled("brushed_copper", (0.95, 0.55, 0.4), 0.35, metallic=1.0),
        principled("blue_ceramic", (0.08, 0.2, 0.8), 0.15),
        patterned("purple_noise", (0.45, 0.1, 0.6), (0.95, 0.9, 0.95), "noise", 9.0, 0.5),
    ]
    box("base", (2.3, 1.5, 0.1), (0, 0, 0.05), base)
    for k, material in enumerate(orbs):
        x, y = -0.84 + 0.56 * (k % 4), 0.38 * (1 if k < 4 else -1)
        cylinder(f"pedestal{k}", 0.12, 0.06, (x, y, 0.13), pedestal)
        sphere(f"orb{k}", 0.24, (x, y, 0.4), material)
    fit_to_box()


def build_cow() -> None:
    """Keenan Crane's "spot" cow: its OBJ imported with its MTL, whose texture (black and white
    spots, pink nose and udder) drives the Base Color; turned z-up and smooth-shaded."""
    # The OBJ is y-up, its head towards +z: the importer turns it z-up (head towards +y), and a
    # quarter turn about z then faces the head towards +x, as the lego's blade.
    bpy.ops.wm.obj_import(filepath=str(ASSETS / "cow" / "cow.obj"), forward_axis="NEGATIVE_Z", up_axis="Y")
    (cow,) = (obj for obj in bpy.context.scene.objects if obj.type == "MESH")
    cow.rotation_euler.z -= math.pi / 2  # XYZ Euler: z turns last, about the world's z axis
    cow.data.shade_smooth()  # the OBJ has no normals: without this every triangle shows
    (material,) = cow.data.materials
    links = material.node_tree.nodes["Principled BSDF"].inputs["Base Color"].links
    image = links[0].from_node.image if links and links[0].from_node.type == "TEX_IMAGE" else None
    if image is None or image.size[0] == 0:  # reading size loads the file; never render a white cow
        raise RuntimeError(f"the cow's texture did not load from {ASSETS / 'cow'}")
    fit_to_box()


BUILDERS = {"lego": build_lego, "chair": build_chair, "materials": build_materials, "cow": build_cow}


# ---- scene set-up shared by built-in and user scenes -------------------------------------------


def add_lighting(scene: bpy.types.Scene) -> None:
    """A sun 40 degrees from the zenith plus a graded sky (ground brown, horizon white, zenith blue).

    The sky lights the shadowed sides and is what glossy and metal surfaces reflect; the film
    is transparent, so it never shows directly.
    """
    world = bpy.data.worlds.new("sky")
    scene.world = world
    nodes, links = world.node_tree.nodes, world.node_tree.links
    coords = nodes.new("ShaderNodeTexCoord")
    split = nodes.new("ShaderNodeSeparateXYZ")
    to_unit = nodes.new("ShaderNodeMapRange")  # direction z in [-1, 1] -> [0, 1]
    to_unit.inputs["From Min"].default_value = -1.0
    ramp = nodes.new("ShaderNodeValToRGB")
    ramp.color_ramp.elements[0].color = (0.2, 0.15, 0.1, 1.0)
    ramp.color_ramp.elements[1].color = (0.3, 0.45, 0.8, 1.0)
    horizon = ramp.color_ramp.elements.new(0.5)
    horizon.color = (0.9, 0.9, 0.85, 1.0)
    links.new(coords.outputs["Generated"], split.inputs["Vector"])
    links.new(split.outputs["Z"], to_unit.inputs["Value"])
    links.new(to_unit.outputs["Result"], ramp.inputs["Fac"])
    links.new(ramp.outputs["Color"], nodes["Background"].inputs["Color"])
    nodes["Background"].inputs["Strength"].default_value = 0.8

    sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
    sun.data.energy = 3.0
    sun.data.angle = math.radians(5)
    sun.rotation_euler = (math.radians(40), 0.0, math.radians(60))
    scene.collection.objects.link(sun)


def load_scene(spec: dict) -> bpy.types.Scene:
    """The scene to render: `{"builtin": name}` builds one of BUILDERS in an empty file;
    `{"blend": path}` opens a user's .blend file and keeps its objects, world and lights."""
    if "blend" in spec:
        bpy.ops.wm.open_mainfile(filepath=str(Path(spec["blend"])), load_ui=False)
        return bpy.context.scene
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    BUILDERS[spec["builtin"]]()
    add_lighting(scene)
    return scene


def configure_render(scene: bpy.types.Scene, width: int, height: int, samples: int, seed: int, threads: int) -> None:
    """Cycles on the CPU, deterministic, transparent film, 8-bit RGBA PNG, no tone mapping."""
    scene.render.engine = "CYCLES"
    cycles = scene.cycles
    cycles.device = "CPU"
    cycles.samples = samples
    cycles.seed, cycles.use_animated_seed = seed, False
    # Adaptive sampling and denoising would make the noise depend on the image content in ways
    # that are harder to reason about; a fixed sample count keeps cost and output predictable.
    cycles.use_adaptive_sampling = False
    cycles.use_denoising = False
    cycles.max_bounces, cycles.diffuse_bounces, cycles.glossy_bounces = 8, 2, 3
    cycles.transmission_bounces, cycles.transparent_max_bounces = 8, 8
    cycles.caustics_reflective = cycles.caustics_refractive = False
    cycles.sample_clamp_indirect = 10.0  # few samples: clamp fireflies from glass and metal
    render = scene.render
    render.resolution_x, render.resolution_y, render.resolution_percentage = width, height, 100
    render.pixel_aspect_x = render.pixel_aspect_y = 1.0
    render.film_transparent = True
    render.threads_mode, render.threads = "FIXED", threads
    render.use_persistent_data = True  # keep the scene's BVH between frames: only the camera moves
    render.use_compositing = render.use_sequencer = False
    render.use_file_extension = False
    settings = render.image_settings
    settings.file_format, settings.color_mode, settings.color_depth = "PNG", "RGBA", "8"
    scene.view_settings.view_transform, scene.view_settings.look = "Standard", "None"
    scene.view_settings.exposure, scene.view_settings.gamma = 0.0, 1.0


def prepare_camera(scene: bpy.types.Scene, camera_angle_x: float) -> bpy.types.Object:
    """The scene's camera (created if it has none) as a free pinhole with horizontal field of
    view `camera_angle_x` (radians) and a centred principal point.

    Constraints, parents and animation are removed: a user's file (e.g. NeRF's lego.blend,
    whose camera tracks an empty) would otherwise override the poses set per frame.
    """
    camera = scene.camera
    if camera is None:
        camera = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
        scene.collection.objects.link(camera)
        scene.camera = camera
    camera.constraints.clear()
    camera.parent = None
    camera.animation_data_clear()
    data = camera.data
    data.type, data.lens_unit, data.sensor_fit = "PERSP", "FOV", "HORIZONTAL"
    data.angle_x = camera_angle_x
    data.shift_x = data.shift_y = 0.0
    data.clip_start, data.clip_end = 0.05, 100.0
    return camera
