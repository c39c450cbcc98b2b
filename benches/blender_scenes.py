# Three scenes of our own, rendered by Blender Cycles into multilayer EXRs exactly as
# Blender writes them (no variance passes, no half buffers): what most kpcn users have.
# Run by benches/quality_blender.sh inside Blender, headless:
#   blender -b --factory-startup --python benches/blender_scenes.py -- SCENE SPP SEED OUT.exr
#
# Scenes (320x180, built from primitives; each provokes a failure mode of issue 15):
#   studio  diffuse, glossy and glass spheres on a floor before a wall, one area light:
#           caustics through glass, glossy highlights, flat walls.
#   slit    a closed room lit only through a narrow slit in one wall by a sun outside:
#           sparse indirect light, nearly black at low sample counts.
#   sunlit  metal and glossy objects on a ground plane under a small, strong sun disc
#           and a sky: HDR highlights in the thousands.
# Settings are Blender's defaults except: CPU, no denoising, no adaptive sampling, view
# transform Standard, the passes kpcn's add-on enables (Diffuse Direct/Indirect/Color,
# Normal, Z), Glossy passes, and Denoising Data (OIDN's albedo and normal).
import math
import sys

import bpy

scene_name, spp, seed, out = sys.argv[sys.argv.index("--") + 1 :]
spp, seed = int(spp), int(seed)

bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
scene.render.engine = "CYCLES"
scene.cycles.device = "CPU"
scene.cycles.samples = spp
scene.cycles.seed = seed
scene.cycles.use_denoising = False
scene.cycles.use_adaptive_sampling = False
scene.render.threads_mode = "FIXED"
scene.render.threads = 2
scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 320, 180, 100
scene.render.image_settings.file_format = "OPEN_EXR_MULTILAYER"
scene.render.image_settings.color_depth = "32"
scene.view_settings.view_transform = "Standard"
scene.render.filepath = out
layer = scene.view_layers[0]
for p in ("diffuse_direct", "diffuse_indirect", "diffuse_color", "glossy_direct", "glossy_indirect",
          "glossy_color", "normal", "z"):
    setattr(layer, "use_pass_" + p, True)
layer.cycles.denoising_store_passes = True


def material(name, kind, color=(0.8, 0.8, 0.8), roughness=0.5, metallic=0.0, strength=0.0):
    m = bpy.data.materials.new(name)
    m.use_nodes = True
    nodes, links = m.node_tree.nodes, m.node_tree.links
    nodes.clear()
    output = nodes.new("ShaderNodeOutputMaterial")
    if kind == "glass":
        bsdf = nodes.new("ShaderNodeBsdfGlass")
        bsdf.inputs["Roughness"].default_value = 0.0
        bsdf.inputs["IOR"].default_value = 1.5
    elif kind == "checker":
        bsdf = nodes.new("ShaderNodeBsdfPrincipled")
        bsdf.inputs["Roughness"].default_value = roughness
        checker = nodes.new("ShaderNodeTexChecker")
        checker.inputs["Scale"].default_value = 8.0
        checker.inputs["Color1"].default_value = (*color, 1)
        checker.inputs["Color2"].default_value = (0.1, 0.1, 0.1, 1)
        links.new(checker.outputs["Color"], bsdf.inputs["Base Color"])
    else:
        bsdf = nodes.new("ShaderNodeBsdfPrincipled")
        bsdf.inputs["Base Color"].default_value = (*color, 1)
        bsdf.inputs["Roughness"].default_value = roughness
        bsdf.inputs["Metallic"].default_value = metallic
    links.new(bsdf.outputs[0], output.inputs["Surface"])
    return m


def add(obj_op, location, scale=(1, 1, 1), mat=None, rotation=(0, 0, 0), **kw):
    obj_op(location=location, rotation=rotation, **kw)
    obj = bpy.context.active_object
    obj.scale = scale
    if mat is not None:
        obj.data.materials.append(mat)
    return obj


def light(kind, location, energy, rotation=(0, 0, 0), size=1.0, angle=None):
    data = bpy.data.lights.new(kind.lower(), kind)
    data.energy = energy
    if kind == "AREA":
        data.size = size
    if angle is not None:
        data.angle = math.radians(angle)
    obj = bpy.data.objects.new(kind.lower(), data)
    obj.location, obj.rotation_euler = location, rotation
    scene.collection.objects.link(obj)


def camera(location, rotation, lens=35):
    data = bpy.data.cameras.new("camera")
    data.lens = lens
    obj = bpy.data.objects.new("camera", data)
    obj.location, obj.rotation_euler = location, [math.radians(a) for a in rotation]
    scene.collection.objects.link(obj)
    scene.camera = obj


def world(strength, color=(1, 1, 1), sky=False):
    w = bpy.data.worlds.new("world")
    w.use_nodes = True
    bg = w.node_tree.nodes["Background"]
    bg.inputs["Strength"].default_value = strength
    bg.inputs["Color"].default_value = (*color, 1)
    if sky:
        tex = w.node_tree.nodes.new("ShaderNodeTexSky")
        tex.sky_type = "NISHITA"
        tex.sun_disc = False
        tex.sun_elevation = math.radians(35)
        w.node_tree.links.new(tex.outputs["Color"], bg.inputs["Color"])
    scene.world = w


sphere = bpy.ops.mesh.primitive_uv_sphere_add
cube = bpy.ops.mesh.primitive_cube_add
plane = bpy.ops.mesh.primitive_plane_add

if scene_name == "studio":
    add(plane, (0, 0, 0), (6, 6, 1), material("floor", "checker", (0.7, 0.7, 0.7), 0.6))
    add(plane, (0, 3, 3), (6, 3, 1), material("wall", "diffuse", (0.75, 0.72, 0.68), 0.9), rotation=(math.radians(90), 0, 0))
    add(sphere, (-1.6, 0.5, 0.6), (0.6, 0.6, 0.6), material("red", "diffuse", (0.7, 0.08, 0.05), 0.8), segments=48, ring_count=24)
    add(sphere, (0.0, 0.2, 0.6), (0.6, 0.6, 0.6), material("glass", "glass"), segments=48, ring_count=24)
    add(sphere, (1.6, 0.6, 0.6), (0.6, 0.6, 0.6), material("chrome", "metal", (0.9, 0.9, 0.9), 0.08, 1.0), segments=48, ring_count=24)
    add(cube, (0.9, -1.0, 0.3), (0.3, 0.3, 0.3), material("blue", "diffuse", (0.1, 0.2, 0.7), 0.3), rotation=(0, 0, 0.6))
    light("AREA", (0, -1.5, 4.0), 400, rotation=(math.radians(20), 0, 0), size=1.0)
    world(0.05)
    camera((0, -6.5, 2.2), (78, 0, 0))
elif scene_name == "slit":
    # A closed 6 x 6 x 3 m room; the right wall is two slabs with a 0.12 m gap between.
    room = material("plaster", "diffuse", (0.8, 0.8, 0.78), 0.9)
    add(cube, (0, 0, -0.1), (3.2, 3.2, 0.1), material("floor", "checker", (0.6, 0.5, 0.4), 0.7))
    add(cube, (0, 0, 3.1), (3.2, 3.2, 0.1), room)
    add(cube, (0, 3.1, 1.5), (3.2, 0.1, 1.6), room)
    add(cube, (0, -3.1, 1.5), (3.2, 0.1, 1.6), room)
    add(cube, (-3.1, 0, 1.5), (0.1, 3.2, 1.6), room)
    add(cube, (3.1, 0, 0.72), (0.1, 3.2, 0.82), room)
    add(cube, (3.1, 0, 2.48), (0.1, 3.2, 0.82), room)
    add(sphere, (-0.8, 0.8, 0.5), (0.5, 0.5, 0.5), material("ball", "diffuse", (0.7, 0.2, 0.1), 0.5), segments=48, ring_count=24)
    add(cube, (0.6, -0.6, 0.4), (0.4, 0.4, 0.4), material("crate", "diffuse", (0.3, 0.5, 0.3), 0.7))
    light("SUN", (8, 0, 4), 6.0, rotation=(0, math.radians(70), 0), angle=1.0)
    world(0.6, sky=True)
    camera((-2.6, -2.6, 1.6), (85, 0, -45), lens=20)
elif scene_name == "sunlit":
    add(plane, (0, 0, 0), (20, 20, 1), material("ground", "checker", (0.5, 0.45, 0.4), 0.8))
    add(sphere, (-1.2, 0, 0.7), (0.7, 0.7, 0.7), material("gold", "metal", (1.0, 0.76, 0.33), 0.05, 1.0), segments=64, ring_count=32)
    add(sphere, (0.6, 1.0, 0.5), (0.5, 0.5, 0.5), material("plastic", "diffuse", (0.1, 0.5, 0.2), 0.15), segments=48, ring_count=24)
    add(cube, (1.3, -0.6, 0.45), (0.45, 0.45, 0.45), material("steel", "metal", (0.8, 0.8, 0.85), 0.02, 1.0), rotation=(0, 0, 0.5))
    light("SUN", (0, 0, 10), 3.0, rotation=(math.radians(40), 0, math.radians(30)), angle=0.5)
    world(0.3, sky=True)
    camera((0, -6.0, 1.8), (80, 0, 0))
else:
    raise SystemExit(f"unknown scene {scene_name!r}: studio, slit or sunlit")

bpy.ops.render.render(write_still=True)
print(f"kpcn-bench: wrote {out}")
