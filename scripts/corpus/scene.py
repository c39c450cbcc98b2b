# A procedural Cycles scene per seed, rendered headless by Debian's Blender 3.4 for kpcn's
# training corpus (scripts/cycles-corpus.sh runs it; models/README.md documents the corpus).
#
#   blender -b --factory-startup --python scripts/corpus/scene.py -- SEED MODE OUT [ARGS]
#
# MODE:
#   noisy OUT_DIR N   N renders of 1 sample each, seeds 0..N-1, sample offset 1 (Cycles shoots
#                     sample 0 through the pixel centre), as OUT_DIR/s0000.exr …
#   raw OUT SPP       one render exactly as Blender writes it: default sampling, seed 1000+SPP
#   ref OUT SPP       the reference: SPP samples, seed 4242
#   describe OUT      the scene's description as JSON, without rendering
# Every mode writes OUT's settings and timings to OUT.json (OUT_DIR/log.json for noisy).
#
# A scene is drawn from the seed alone, so a seed always rebuilds the same scene. Settings
# (`stage`): studio (ground, backdrop, area lights), outdoor (sun and Nishita sky), interior
# (a closed room lit through openings: windows, a skylight or slits), night (tiny intense
# lamps and spots, emissive bulbs, glass for caustics). Seeds from SUN_PATCH_SEEDS on build
# the sun-patch series instead: closed rooms lit by a sun shaft through a small skylight or
# slits in the wall facing the sun, under a dim sky and no lamp, so that at a few samples
# most of the room is dark, sparse indirect light beside a hard sun patch. From AIMED_SEEDS
# on, the series draws a stronger sun and aims the camera along the shaft (from the opening
# to where the sun lands), so the patch, the opening and the dark beside them are in view.
# Objects: primitives and displaced or subdivided meshes with Principled materials on
# procedural textures, glass, metals and rough glossy surfaces. Cameras are random; a share
# gets thin-lens defocus.
#
# The render protocol is the dev set's (../shared/data/cycles-dev/README.md): CPU, 2 threads,
# 320x180, PMJ, Blackman-Harris 1.5 px, 8 bounces, caustics on, no clamping, Filter Glossy 0,
# no adaptive sampling, no denoising, view transform Standard, multilayer EXR float ZIP.
import json
import math
import os
import random
import sys
import time

import bpy
from mathutils import Vector

WIDTH, HEIGHT = 320, 180
STAGES = ("studio", "outdoor", "interior", "night")
# The first seed of the sun-patch series; the seeds below it keep the four stages above.
SUN_PATCH_SEEDS = 100000
# The first seed of the aimed sun-patch series (a stronger sun, the camera on the shaft).
AIMED_SEEDS = 110000
# The sun's azimuth facing each wall of a room (+y, -y, +x, -x), as `sky` turns it.
WALL_AZIMUTH = (math.pi / 2, -math.pi / 2, 0.0, math.pi)


def setup_render(scene):
    scene.render.engine = "CYCLES"
    c = scene.cycles
    c.device = "CPU"
    c.feature_set = "SUPPORTED"
    c.use_denoising = False
    c.use_adaptive_sampling = False
    c.sampling_pattern = "PROGRESSIVE_MULTI_JITTER"
    c.pixel_filter_type = "BLACKMAN_HARRIS"
    c.filter_width = 1.5
    c.sample_clamp_direct = 0.0
    c.sample_clamp_indirect = 0.0
    c.blur_glossy = 0.0
    c.caustics_reflective = True
    c.caustics_refractive = True
    c.max_bounces = 8
    c.diffuse_bounces = c.glossy_bounces = c.transmission_bounces = 8
    c.volume_bounces = 0
    c.transparent_max_bounces = 8
    c.light_sampling_threshold = 0.01
    scene.render.threads_mode = "FIXED"
    scene.render.threads = 2
    scene.render.resolution_x, scene.render.resolution_y = WIDTH, HEIGHT
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = False
    scene.render.use_persistent_data = True
    scene.view_settings.view_transform = "Standard"
    settings = scene.render.image_settings
    settings.file_format = "OPEN_EXR_MULTILAYER"
    settings.color_depth = "32"
    settings.exr_codec = "ZIP"
    layer = scene.view_layers[0]
    for p in ("z", "mist", "normal", "diffuse_direct", "diffuse_indirect", "diffuse_color", "glossy_direct",
              "glossy_indirect", "glossy_color", "transmission_direct", "transmission_indirect",
              "transmission_color", "emit", "environment"):
        setattr(layer, "use_pass_" + p, True)
    layer.cycles.denoising_store_passes = True
    mist = scene.world.mist_settings
    mist.start, mist.depth, mist.falloff = 0.0, 10000.0, "LINEAR"


class Builder:
    """Draws one scene from a seeded generator; `info` describes what was drawn."""

    def __init__(self, seed):
        self.rng = random.Random(seed)
        self.seed = seed
        self.info = {"seed": seed, "objects": [], "lights": []}
        # The aimed series' sun shaft: (its opening, where it lands), for the camera.
        self.shaft = None
        self.scene = bpy.context.scene

    # ---- materials -------------------------------------------------------------------
    def colour(self, lo=0.05, hi=0.9):
        r = self.rng
        h, s, v = r.random(), r.uniform(0.0, 0.9), r.uniform(lo, hi)
        # HSV to RGB, so saturated and grey colours both occur.
        i = int(h * 6) % 6
        f = h * 6 - int(h * 6)
        p, q, t = v * (1 - s), v * (1 - s * f), v * (1 - s * (1 - f))
        return [(v, t, p), (q, v, p), (p, v, t), (p, q, v), (t, p, v), (v, p, q)][i]

    def texture(self, nodes, links, target, coords):
        """A procedural texture driving a colour socket, or nothing (a plain colour)."""
        r = self.rng
        kind = r.choice(["plain", "plain", "noise", "voronoi", "checker", "wave", "magic", "brick"])
        if kind == "plain":
            target.default_value = (*self.colour(), 1)
            return kind
        tex = nodes.new({"noise": "ShaderNodeTexNoise", "voronoi": "ShaderNodeTexVoronoi",
                         "checker": "ShaderNodeTexChecker", "wave": "ShaderNodeTexWave",
                         "magic": "ShaderNodeTexMagic", "brick": "ShaderNodeTexBrick"}[kind])
        links.new(coords.outputs["Object"], tex.inputs["Vector"])
        tex.inputs["Scale"].default_value = r.choice([r.uniform(0.5, 4), r.uniform(4, 30)])
        if kind == "noise":
            tex.inputs["Detail"].default_value = r.uniform(1, 12)
        ramp = nodes.new("ShaderNodeValToRGB")
        ramp.color_ramp.elements[0].color = (*self.colour(0.02, 0.5), 1)
        ramp.color_ramp.elements[1].color = (*self.colour(0.3, 0.95), 1)
        if kind == "checker":
            links.new(tex.outputs["Fac"], ramp.inputs["Fac"])
        elif kind == "voronoi":
            links.new(tex.outputs["Distance"], ramp.inputs["Fac"])
        else:
            links.new(tex.outputs["Fac"] if "Fac" in tex.outputs else tex.outputs[1], ramp.inputs["Fac"])
        links.new(ramp.outputs["Color"], target)
        return kind

    def material(self, kind=None):
        r = self.rng
        kind = kind or r.choices(["diffuse", "plastic", "metal", "glass", "rough_glass", "emissive"],
                                 [5, 4, 3, 2, 1, 0.4])[0]
        m = bpy.data.materials.new(f"{kind}-{len(bpy.data.materials)}")
        m.use_nodes = True
        nodes, links = m.node_tree.nodes, m.node_tree.links
        nodes.clear()
        out = nodes.new("ShaderNodeOutputMaterial")
        coords = nodes.new("ShaderNodeTexCoord")
        desc = {"kind": kind}
        if kind in ("glass", "rough_glass"):
            bsdf = nodes.new("ShaderNodeBsdfGlass")
            bsdf.inputs["Color"].default_value = (*[0.75 + 0.25 * c for c in self.colour(0.6, 1)], 1)
            bsdf.inputs["IOR"].default_value = r.uniform(1.3, 1.7)
            bsdf.inputs["Roughness"].default_value = 0.0 if kind == "glass" else r.uniform(0.02, 0.3)
            links.new(bsdf.outputs[0], out.inputs["Surface"])
            return m, desc
        if kind == "emissive":
            em = nodes.new("ShaderNodeEmission")
            em.inputs["Color"].default_value = (*self.colour(0.6, 1), 1)
            em.inputs["Strength"].default_value = 10 ** r.uniform(0.5, 2.5)
            desc["strength"] = em.inputs["Strength"].default_value
            links.new(em.outputs[0], out.inputs["Surface"])
            return m, desc
        bsdf = nodes.new("ShaderNodeBsdfPrincipled")
        desc["texture"] = self.texture(nodes, links, bsdf.inputs["Base Color"], coords)
        if kind == "diffuse":
            bsdf.inputs["Roughness"].default_value = r.uniform(0.5, 1.0)
            bsdf.inputs["Specular"].default_value = r.uniform(0.0, 0.5)
        elif kind == "plastic":
            bsdf.inputs["Roughness"].default_value = r.choice([r.uniform(0.0, 0.1), r.uniform(0.1, 0.5)])
            bsdf.inputs["Specular"].default_value = r.uniform(0.3, 1.0)
            bsdf.inputs["Clearcoat"].default_value = r.choice([0.0, 0.0, r.uniform(0.3, 1.0)])
        else:  # metal
            bsdf.inputs["Metallic"].default_value = 1.0
            bsdf.inputs["Roughness"].default_value = r.choice([r.uniform(0.0, 0.08), r.uniform(0.08, 0.5)])
            if r.random() < 0.5:
                bsdf.inputs["Base Color"].default_value = (*self.colour(0.5, 1.0), 1)
                for l in list(bsdf.inputs["Base Color"].links):
                    links.remove(l)
        desc["roughness"] = round(bsdf.inputs["Roughness"].default_value, 3)
        if r.random() < 0.3:
            bump = nodes.new("ShaderNodeBump")
            noise = nodes.new("ShaderNodeTexNoise")
            noise.inputs["Scale"].default_value = r.uniform(5, 60)
            links.new(coords.outputs["Object"], noise.inputs["Vector"])
            links.new(noise.outputs["Fac"], bump.inputs["Height"])
            bump.inputs["Strength"].default_value = r.uniform(0.05, 0.5)
            links.new(bump.outputs["Normal"], bsdf.inputs["Normal"])
            desc["bump"] = True
        links.new(bsdf.outputs[0], out.inputs["Surface"])
        return m, desc

    def assign(self, obj, kind=None):
        m, desc = self.material(kind)
        obj.data.materials.clear()
        obj.data.materials.append(m)
        return desc

    # ---- geometry --------------------------------------------------------------------
    def smooth(self, obj):
        for p in obj.data.polygons:
            p.use_smooth = True

    def primitive(self, location, size):
        r = self.rng
        kind = r.choices(["sphere", "displaced", "cube", "cylinder", "torus", "monkey", "cone", "blob"],
                         [3, 2, 2, 2, 1.5, 1, 1, 1.5])[0]
        ops = bpy.ops.mesh
        if kind in ("sphere",):
            ops.primitive_uv_sphere_add(radius=size, location=location, segments=48, ring_count=24)
        elif kind in ("displaced", "blob"):
            ops.primitive_ico_sphere_add(radius=size, location=location, subdivisions=5)
        elif kind == "cube":
            ops.primitive_cube_add(size=size * 1.6, location=location)
        elif kind == "cylinder":
            ops.primitive_cylinder_add(radius=size * 0.6, depth=size * r.uniform(1, 3), location=location, vertices=48)
        elif kind == "torus":
            ops.primitive_torus_add(major_radius=size, minor_radius=size * r.uniform(0.15, 0.4), location=location)
        elif kind == "monkey":
            ops.primitive_monkey_add(size=size * 1.5, location=location)
        else:
            ops.primitive_cone_add(radius1=size * 0.8, depth=size * 2, location=location, vertices=48)
        obj = bpy.context.active_object
        obj.rotation_euler = (r.uniform(-0.4, 0.4), r.uniform(-0.4, 0.4), r.uniform(0, 2 * math.pi))
        if kind in ("displaced", "blob"):
            tex = bpy.data.textures.new(f"disp-{obj.name}", "CLOUDS" if kind == "blob" else "VORONOI")
            tex.noise_scale = r.uniform(0.2, 0.8) * size
            mod = obj.modifiers.new("displace", "DISPLACE")
            mod.texture = tex
            mod.strength = size * r.uniform(0.1, 0.4)
        if kind == "cube":
            bev = obj.modifiers.new("bevel", "BEVEL")
            bev.width = size * 0.05
            bev.segments = 3
        if kind in ("monkey", "displaced", "blob"):
            obj.modifiers.new("subsurf", "SUBSURF").levels = 1
        if kind != "cube":
            self.smooth(obj)
        return obj, kind

    def plane(self, size, location, rotation=(0, 0, 0), kind="diffuse"):
        bpy.ops.mesh.primitive_plane_add(size=size, location=location, rotation=rotation)
        obj = bpy.context.active_object
        self.assign(obj, kind)
        return obj

    def box(self, location, dims, kind="diffuse"):
        bpy.ops.mesh.primitive_cube_add(size=1, location=location)
        obj = bpy.context.active_object
        obj.scale = dims
        self.assign(obj, kind)
        return obj

    def scatter(self, n, extent, ground_z=0.0):
        """n objects on the ground within ±extent, not overlapping."""
        r = self.rng
        placed = []
        for _ in range(n * 10):
            if len(placed) == n:
                break
            size = r.uniform(0.15, 0.7) * (extent / 2.5) ** 0.5
            x, y = r.uniform(-extent, extent), r.uniform(-extent, extent)
            if any((x - px) ** 2 + (y - py) ** 2 < (size + ps) ** 2 for px, py, ps in placed):
                continue
            z = ground_z + size * r.choice([1.0, 1.0, 1.0, r.uniform(1.5, 3)])
            obj, kind = self.primitive((x, y, z), size)
            desc = self.assign(obj)
            placed.append((x, y, size))
            self.info["objects"].append({"shape": kind, "size": round(size, 3), **desc})
        return placed

    # ---- lights ------------------------------------------------------------------------
    def light(self, kind, location, power, size=0.1, target=(0, 0, 0), colour=None, spot_deg=45):
        data = bpy.data.lights.new(f"{kind}-{len(bpy.data.lights)}", kind)
        data.energy = power
        data.color = colour or (1.0, 1.0, 1.0)
        if kind == "AREA":
            data.size = size
        elif kind in ("POINT", "SPOT"):
            data.shadow_soft_size = size
        if kind == "SPOT":
            data.spot_size = math.radians(spot_deg)
            data.spot_blend = self.rng.uniform(0, 0.5)
        obj = bpy.data.objects.new(data.name, data)
        self.scene.collection.objects.link(obj)
        obj.location = location
        direction = Vector(target) - Vector(location)
        obj.rotation_euler = direction.to_track_quat("-Z", "Y").to_euler()
        self.info["lights"].append({"kind": kind, "power": round(power, 3), "size": round(size, 4)})
        return obj

    def warm(self):
        t = self.rng.uniform(0, 1)
        return (1.0, 0.75 + 0.25 * t, 0.5 + 0.5 * t)

    def world_colour(self, colour, strength):
        w = self.scene.world
        w.use_nodes = True
        bg = w.node_tree.nodes["Background"]
        bg.inputs["Color"].default_value = (*colour, 1)
        bg.inputs["Strength"].default_value = strength

    def sky(self, elevation, azimuth, strength, sun_strength):
        w = self.scene.world
        w.use_nodes = True
        nodes, links = w.node_tree.nodes, w.node_tree.links
        sky = nodes.new("ShaderNodeTexSky")
        sky.sky_type = "NISHITA"
        sky.sun_disc = False
        sky.sun_elevation, sky.sun_rotation = elevation, azimuth
        sky.air_density = self.rng.uniform(0.5, 3)
        sky.dust_density = self.rng.uniform(0, 4)
        links.new(sky.outputs["Color"], nodes["Background"].inputs["Color"])
        nodes["Background"].inputs["Strength"].default_value = strength
        # The sun lamp matches the sky's sun: rotation so -Z points from the sun.
        sun = bpy.data.lights.new("sun", "SUN")
        sun.energy = sun_strength
        sun.angle = math.radians(self.rng.uniform(0.3, 3))
        obj = bpy.data.objects.new("sun", sun)
        self.scene.collection.objects.link(obj)
        obj.rotation_euler = (math.pi / 2 - elevation, 0, azimuth + math.pi / 2)
        self.info["lights"].append({"kind": "SUN+SKY", "power": sun_strength, "elevation_deg": round(math.degrees(elevation), 1)})

    # ---- stages -------------------------------------------------------------------------
    def studio(self):
        r = self.rng
        extent = r.uniform(1.5, 3.5)
        self.plane(60, (0, 0, 0))
        if r.random() < 0.7:
            self.plane(60, (0, extent * 2.5, 0), rotation=(math.pi / 2, 0, 0))
        self.scatter(r.randint(3, 8), extent)
        for _ in range(r.randint(1, 3)):
            az, el = r.uniform(0, 2 * math.pi), r.uniform(0.3, 1.3)
            d = r.uniform(3, 8)
            loc = (d * math.cos(az) * math.cos(el), d * math.sin(az) * math.cos(el), d * math.sin(el))
            self.light("AREA", loc, 10 ** r.uniform(1.7, 3.2), size=r.uniform(0.1, 3), colour=self.warm())
        self.world_colour(self.colour(0.2, 1.0), r.uniform(0.0, 0.4))
        return extent

    def outdoor(self):
        r = self.rng
        extent = r.uniform(2, 5)
        self.plane(400, (0, 0, 0))
        self.scatter(r.randint(3, 9), extent)
        self.sky(r.uniform(0.05, 1.3), r.uniform(0, 2 * math.pi), r.uniform(0.05, 0.6), 10 ** r.uniform(0, 1))
        return extent

    def interior(self, sun_patch=False):
        """The room; `sun_patch` draws the sun-patch series' openings and light."""
        r = self.rng
        w, d, h = r.uniform(4, 9), r.uniform(4, 9), r.uniform(2.5, 4)
        t = 0.2
        wall = "diffuse"
        # Floor, ceiling and four walls as boxes; openings are holes cut by boolean
        # differences, so light enters only through them.
        self.box((0, 0, -t / 2), (w + 2 * t, d + 2 * t, t), kind=r.choice(["diffuse", "diffuse", "plastic"]))
        ceiling = self.box((0, 0, h + t / 2), (w + 2 * t, d + 2 * t, t), kind=wall)
        walls = [self.box((0, d / 2 + t / 2, h / 2), (w + 2 * t, t, h), kind=wall),
                 self.box((0, -d / 2 - t / 2, h / 2), (w + 2 * t, t, h), kind=wall),
                 self.box((w / 2 + t / 2, 0, h / 2), (t, d, h), kind=wall),
                 self.box((-w / 2 - t / 2, 0, h / 2), (t, d, h), kind=wall)]
        opening = r.choice(["skylight", "slits"] if sun_patch else ["window", "window", "skylight", "slits"])
        cutters, wall = [], None
        if opening == "window":
            for _ in range(r.randint(1, 2)):
                i = r.randrange(4)
                ow, oh = r.uniform(0.6, 3), r.uniform(0.6, 1.8)
                z = r.uniform(0.5, h - oh / 2 - 0.2)
                if i < 2:
                    loc = (r.uniform(-w / 3, w / 3), (d / 2 + t / 2) * (1 if i == 0 else -1), z)
                    dims = (ow, t * 3, oh)
                else:
                    loc = ((w / 2 + t / 2) * (1 if i == 2 else -1), r.uniform(-d / 3, d / 3), z)
                    dims = (t * 3, ow, oh)
                cutters.append((walls[i], loc, dims))
        elif opening == "skylight":
            s = r.uniform(0.4, 1.0) if sun_patch else r.uniform(0.5, 1.5)
            cutters.append((ceiling, (r.uniform(-w / 4, w / 4), r.uniform(-d / 4, d / 4), h + t / 2), (s, s, t * 3)))
        else:
            i = wall = r.randrange(4)
            for k in range(r.randint(1, 3)):
                z = r.uniform(0.8, h - 0.3)
                dims = (r.uniform(1, 3), t * 3, r.uniform(0.03, 0.1)) if i < 2 else (t * 3, r.uniform(1, 3), r.uniform(0.03, 0.1))
                loc = (0, (d / 2 + t / 2) * (1 if i == 0 else -1), z) if i < 2 else ((w / 2 + t / 2) * (1 if i == 2 else -1), 0, z)
                cutters.append((walls[i], loc, dims))
        for target, loc, dims in cutters:
            bpy.ops.mesh.primitive_cube_add(size=1, location=loc)
            c = bpy.context.active_object
            c.scale = dims
            mod = target.modifiers.new("opening", "BOOLEAN")
            mod.operation, mod.object = "DIFFERENCE", c
            c.hide_render = True
            c.hide_viewport = True
        self.info["opening"] = opening
        self.scatter(r.randint(3, 7), min(w, d) / 2 - 0.6)
        if not sun_patch:
            self.sky(r.uniform(0.15, 1.3), r.uniform(0, 2 * math.pi), r.uniform(0.3, 1.5), 10 ** r.uniform(0.3, 1.6))
        else:
            # Drawn in the order the calls before AIMED_SEEDS drew them, so those seeds keep
            # their scenes.
            aimed = self.seed >= AIMED_SEEDS
            if wall is None:  # high sun, so that the skylight's shaft lands on the floor
                elevation, azimuth = r.uniform(0.8, 1.4), r.uniform(0, 2 * math.pi)
            else:  # low sun facing the slits' wall
                elevation, azimuth = r.uniform(0.15, 0.6), WALL_AZIMUTH[wall] + r.uniform(-0.4, 0.4)
            strength = r.uniform(0.05, 0.4)
            sun = 10 ** (r.uniform(1.5, 2.5) if aimed else r.uniform(1, 2))
            self.sky(elevation, azimuth, strength, sun)
            if aimed:
                self.shaft = self.sun_landing(cutters[0][1], elevation, azimuth, w, d, h)
        if not sun_patch and r.random() < 0.3:  # a lamp inside too
            self.light("POINT", (r.uniform(-w / 3, w / 3), r.uniform(-d / 3, d / 3), h - 0.3),
                       10 ** r.uniform(1, 2.3), size=r.uniform(0.02, 0.2), colour=self.warm())
        self.info["room"] = [round(w, 2), round(d, 2), round(h, 2)]
        return min(w, d) / 2 - 0.5, h

    @staticmethod
    def sun_landing(opening, elevation, azimuth, w, d, h):
        """Where the sun entering at `opening` (a point on the ceiling or a wall) first
        lands inside the room: (the opening, the landing point)."""
        o = Vector((opening[0], opening[1], min(opening[2], h)))
        # The sun sits towards (cos e cos a, cos e sin a, sin e) (`sky`); light travels away.
        ray = -Vector((math.cos(elevation) * math.cos(azimuth), math.cos(elevation) * math.sin(azimuth),
                       math.sin(elevation)))
        hits = [o.z / -ray.z]
        for i, half in ((0, w / 2), (1, d / 2)):
            if abs(ray[i]) > 1e-6:
                hits.append((math.copysign(half, ray[i]) - o[i]) / ray[i])
        t = min(x for x in hits if x > 1e-3)
        return o, o + ray * t

    def night(self):
        r = self.rng
        extent = r.uniform(1.5, 3)
        self.plane(60, (0, 0, 0), kind=r.choice(["diffuse", "plastic"]))
        if r.random() < 0.6:
            self.plane(60, (0, extent * 2.2, 0), rotation=(math.pi / 2, 0, 0))
        self.scatter(r.randint(2, 5), extent)
        for _ in range(r.randint(1, 3)):  # glass and mirror-like objects for caustics
            x, y = r.uniform(-extent, extent), r.uniform(-extent, extent)
            size = r.uniform(0.2, 0.6)
            obj, kind = self.primitive((x, y, size), size)
            desc = self.assign(obj, r.choice(["glass", "glass", "metal"]))
            self.info["objects"].append({"shape": kind, "size": round(size, 3), **desc})
        for _ in range(r.randint(1, 3)):
            loc = (r.uniform(-extent, extent), r.uniform(-extent, extent), r.uniform(1.5, 4))
            if r.random() < 0.5:
                self.light("SPOT", loc, 10 ** r.uniform(2, 3.3), size=r.uniform(0.005, 0.05),
                           target=(r.uniform(-1, 1), r.uniform(-1, 1), 0), colour=self.warm(), spot_deg=r.uniform(20, 80))
            else:
                self.light("POINT", loc, 10 ** r.uniform(1.5, 3), size=r.uniform(0.005, 0.05), colour=self.warm())
        for _ in range(r.randint(0, 6)):  # small emissive bulbs, often out of focus
            bpy.ops.mesh.primitive_uv_sphere_add(radius=r.uniform(0.02, 0.08),
                                                 location=(r.uniform(-8, 8), r.uniform(2, 14), r.uniform(0.2, 3)))
            self.assign(bpy.context.active_object, "emissive")
        self.world_colour(self.colour(0.2, 1.0), r.uniform(0.0, 0.05))
        return extent

    # ---- camera --------------------------------------------------------------------------
    def camera(self, stage, extent, height=None):
        r = self.rng
        data = bpy.data.cameras.new("camera")
        data.lens = r.choice([r.uniform(20, 35), r.uniform(35, 60), r.uniform(60, 100)])
        data.sensor_width = 36
        cam = bpy.data.objects.new("camera", data)
        self.scene.collection.objects.link(cam)
        self.scene.camera = cam
        target = Vector((r.uniform(-extent, extent) * 0.4, r.uniform(-extent, extent) * 0.4, r.uniform(0.1, 0.8)))
        if stage in ("interior", "sunpatch"):
            dist = r.uniform(0.5, 1.0) * extent
            az = r.uniform(0, 2 * math.pi)
            loc = Vector((dist * math.cos(az), dist * math.sin(az), r.uniform(0.6, height - 0.4)))
            target = Vector((-loc.x * r.uniform(0.3, 1), -loc.y * r.uniform(0.3, 1), r.uniform(0.3, height - 0.5)))
            if self.shaft:  # the aimed series: a point on the shaft
                opening, landing = self.shaft
                target = opening.lerp(landing, r.uniform(0.2, 1.0))
                target += Vector((r.uniform(-0.3, 0.3), r.uniform(-0.3, 0.3), r.uniform(-0.3, 0.3)))
                if (target - loc).length < 1.0:  # too close to frame the patch: the far side
                    loc.x, loc.y = -loc.x, -loc.y
                self.info["shaft"] = [[round(v, 2) for v in opening], [round(v, 2) for v in landing]]
            data.lens = r.uniform(14, 30)
        else:
            dist = extent * r.uniform(1.5, 3.5) * (data.lens / 35) ** 0.7
            az = r.uniform(-math.pi, 0) if stage in ("studio", "night") else r.uniform(0, 2 * math.pi)
            el = r.uniform(0.05, 0.8)
            loc = target + Vector((dist * math.cos(az) * math.cos(el), dist * math.sin(az) * math.cos(el),
                                   dist * math.sin(el)))
            loc.z = max(loc.z, 0.15)
        cam.location = loc
        cam.rotation_euler = (target - loc).to_track_quat("-Z", "Y").to_euler()
        cam.rotation_euler.y += r.uniform(-0.05, 0.05)
        dof = r.random() < (0.6 if stage == "night" else 0.3)
        data.dof.use_dof = dof
        if dof:
            data.dof.focus_distance = (target - loc).length * r.uniform(0.6, 1.1)
            data.dof.aperture_fstop = 10 ** r.uniform(-0.3, 0.6)
        self.info["camera"] = {"lens_mm": round(data.lens, 1), "dof": dof,
                               "fstop": round(data.dof.aperture_fstop, 2) if dof else None}

    def build(self):
        if self.seed >= SUN_PATCH_SEEDS:
            stage = "sunpatch"
        else:
            stage = STAGES[self.seed % len(STAGES)] if self.rng.random() < 0.5 else self.rng.choice(STAGES)
        self.info["stage"] = stage
        height = None
        if stage in ("interior", "sunpatch"):
            extent, height = self.interior(sun_patch=stage == "sunpatch")
        else:
            extent = getattr(self, stage)()
        self.camera(stage, extent, height)
        return self.info


def render(scene, path, samples, seed, offset):
    scene.cycles.samples = samples
    scene.cycles.seed = seed
    scene.cycles.sample_offset = offset
    scene.render.filepath = path
    start = time.time()
    bpy.ops.render.render(write_still=True)
    return time.time() - start


def main():
    args = sys.argv[sys.argv.index("--") + 1:]
    seed, mode, out = int(args[0]), args[1], args[2]
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.world = bpy.data.worlds.new("World")
    setup_render(scene)
    info = Builder(seed).build()
    log = {"mode": mode, "blender": bpy.app.version_string, "scene": info}
    if mode == "noisy":
        n = int(args[3])
        os.makedirs(out, exist_ok=True)
        times = [render(scene, os.path.join(out, f"s{i:04d}.exr"), 1, i, 1) for i in range(n)]
        log.update({"samples": 1, "renders": n, "seeds": [0, n - 1], "sample_offset": 1, "seconds": times})
        log_path = os.path.join(out, "log.json")
    elif mode in ("raw", "ref"):
        spp = int(args[3])
        seed_used = 1000 + spp if mode == "raw" else 4242
        seconds = render(scene, out, spp, seed_used, 0)
        log.update({"samples": spp, "seed": seed_used, "sample_offset": 0, "seconds": seconds})
        log_path = out + ".json"
    elif mode == "describe":
        log_path = out
    else:
        raise SystemExit(f"unknown mode {mode!r}: noisy, raw, ref or describe")
    with open(log_path, "w") as f:
        json.dump(log, f, indent=1)


main()
