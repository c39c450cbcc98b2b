# kpcn for Blender 3.4+: denoise Cycles renders with kpcn through its C ABI (ctypes).
#
# - Render > "Denoise Last Render (kpcn)": saves the last render as a multilayer EXR,
#   denoises it and opens the result as the image "kpcn Denoised".
# - Output Properties > kpcn > "Denoise written frames": after each frame of an animation
#   is written (a multilayer EXR), denoises it in place, keeping every pass and adding
#   `<ViewLayer>.Denoised`, which the compositor's Image node lists as a pass.
# - "Enable kpcn passes" turns on the passes kpcn reads: Diffuse Direct/Indirect/Color,
#   Normal and Z (Combined is always there).
#
# The library is found through the add-on preference "Library", else $KPCN_LIBRARY, else
# the system's libkpcn.so.1 (scripts/install.sh PREFIX, then LD_LIBRARY_PATH or ldconfig).
import ctypes
import ctypes.util
import os
import tempfile

import bpy

bl_info = {
    "name": "kpcn denoiser",
    "author": "kpcn",
    "version": (0, 1, 0),
    "blender": (3, 4, 0),
    "location": "Render menu; Properties > Output > kpcn",
    "description": "Kernel-predicting Monte Carlo denoiser for Cycles multilayer EXRs",
    "category": "Render",
}


class KpcnError(RuntimeError):
    """A kpcn call failed; the message is the library's."""


class _Options(ctypes.Structure):
    # KpcnOptions in include/kpcn.h.
    _fields_ = [
        ("struct_size", ctypes.c_size_t),
        ("threads", ctypes.c_uint32),
        ("max_memory_mb", ctypes.c_uint32),
        ("model_name", ctypes.c_char_p),
        ("model_path", ctypes.c_char_p),
        ("model_data", ctypes.c_void_p),
        ("model_size", ctypes.c_size_t),
        ("allow_untrained", ctypes.c_bool),
    ]


class _FileOptions(ctypes.Structure):
    # KpcnFileOptions in include/kpcn.h.
    _fields_ = [
        ("struct_size", ctypes.c_size_t),
        ("layer", ctypes.c_char_p),
        ("aovs", ctypes.c_bool),
        ("separate", ctypes.c_bool),
        ("no_clobber", ctypes.c_bool),
        ("layout", ctypes.c_int32),
        ("in_place", ctypes.c_bool),
    ]


LAYOUT_CYCLES = 2
_lib = None


def library(path=""):
    """The loaded libkpcn (loaded once), with argument types declared."""
    global _lib
    if _lib is not None:
        return _lib
    path = path or os.environ.get("KPCN_LIBRARY") or ctypes.util.find_library("kpcn") or "libkpcn.so.1"
    if os.path.isdir(path):
        path = os.path.join(path, "libkpcn.so.1")
    try:
        lib = ctypes.CDLL(path)
    except OSError as e:
        raise KpcnError(f"cannot load the kpcn library ({e}); install it with scripts/install.sh PREFIX "
                        "and set the add-on's Library preference or $KPCN_LIBRARY") from None
    p, c = ctypes.POINTER, ctypes.c_char_p
    lib.kpcn_last_error.restype = c
    lib.kpcn_version_string.restype = c
    lib.kpcn_options_init.argtypes = [p(_Options)]
    lib.kpcn_denoiser_new.argtypes = [p(_Options), p(ctypes.c_void_p)]
    lib.kpcn_denoiser_free.argtypes = [ctypes.c_void_p]
    lib.kpcn_file_options_init.argtypes = [p(_FileOptions)]
    lib.kpcn_denoise_file.argtypes = [ctypes.c_void_p, c, c, p(_FileOptions)]
    for f in ("options_init", "denoiser_new", "denoiser_free", "file_options_init", "denoise_file"):
        getattr(lib, "kpcn_" + f).restype = ctypes.c_int32
    # The structs above must be the library's: their size is their version.
    o, fo = _Options(), _FileOptions()
    lib.kpcn_options_init(ctypes.byref(o))
    lib.kpcn_file_options_init(ctypes.byref(fo))
    if (o.struct_size, fo.struct_size) != (ctypes.sizeof(o), ctypes.sizeof(fo)):
        raise KpcnError("this add-on does not match the loaded kpcn library "
                        f"{lib.kpcn_version_string().decode()}; install the add-on from the same version")
    _lib = lib
    return lib


def _check(lib, status):
    if status != 0:
        raise KpcnError(lib.kpcn_last_error().decode(errors="replace"))


def denoise_file(source, target, layer, threads=0, model="", lib_path=""):
    """Denoises the Cycles multilayer EXR `source` into `target` (may be the same file: the
    layer is then added in place, atomically), adding the layer `layer` and keeping every
    pass."""
    lib = library(lib_path)
    options = _Options()
    lib.kpcn_options_init(ctypes.byref(options))
    options.threads = threads
    # `auto`, as `kpcn denoise` does: Blender writes no variance passes, so this picks the
    # shipped `spatial` model, trained on the spatial estimates kpcn makes for such files.
    model = model or "auto"
    attr = "model_path" if model.endswith(".safetensors") else "model_name"
    setattr(options, attr, model.encode())
    handle = ctypes.c_void_p()
    _check(lib, lib.kpcn_denoiser_new(ctypes.byref(options), ctypes.byref(handle)))
    try:
        fo = _FileOptions()
        lib.kpcn_file_options_init(ctypes.byref(fo))
        fo.layer = layer.encode()
        fo.layout = LAYOUT_CYCLES
        fo.in_place = os.path.realpath(source) == os.path.realpath(target)
        _check(lib, lib.kpcn_denoise_file(handle, os.fsencode(source), os.fsencode(target), ctypes.byref(fo)))
    finally:
        lib.kpcn_denoiser_free(handle)


def output_layer(scene):
    """`<ViewLayer>.Denoised` for the view layer kpcn denoises: the first rendered one by
    name (kpcn reads one view layer per file)."""
    names = sorted(vl.name for vl in scene.view_layers if vl.use)
    return f"{names[0] if names else 'ViewLayer'}.Denoised"


def _prefs(context):
    addon = context.preferences.addons.get(__name__)
    return addon.preferences if addon else None


class KpcnPreferences(bpy.types.AddonPreferences):
    bl_idname = __name__
    library: bpy.props.StringProperty(name="Library", subtype="FILE_PATH",
                                      description="libkpcn.so.1, or the folder holding it (empty: $KPCN_LIBRARY or the system's)")
    model: bpy.props.StringProperty(name="Model", description="A model name or .safetensors file (empty: auto, which picks `spatial`, trained for files without variance passes)")
    threads: bpy.props.IntProperty(name="Threads", min=0, default=0, description="0 = every core")

    def draw(self, context):
        for p in ("library", "model", "threads"):
            self.layout.prop(self, p)


class KpcnSettings(bpy.types.PropertyGroup):
    auto: bpy.props.BoolProperty(
        name="Denoise written frames",
        description="After each frame is written as a multilayer EXR, denoise it in place (every pass is kept)")


def _settings_of(context):
    prefs = _prefs(context)
    if prefs is None:
        return {}
    return {"threads": prefs.threads, "model": prefs.model, "lib_path": bpy.path.abspath(prefs.library)}


class KPCN_OT_enable_passes(bpy.types.Operator):
    """Turn on the passes kpcn reads (Diffuse Direct/Indirect/Color, Normal, Z)"""
    bl_idname = "kpcn.enable_passes"
    bl_label = "Enable kpcn passes"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        for vl in context.scene.view_layers:
            for p in ("diffuse_direct", "diffuse_indirect", "diffuse_color", "normal", "z"):
                setattr(vl, "use_pass_" + p, True)
        return {"FINISHED"}


class KPCN_OT_denoise_render(bpy.types.Operator):
    """Denoise the last render with kpcn into the image "kpcn Denoised\""""
    bl_idname = "kpcn.denoise_render"
    bl_label = "Denoise Last Render (kpcn)"

    def execute(self, context):
        scene = context.scene
        result = bpy.data.images.get("Render Result")
        if result is None:
            self.report({"ERROR"}, "No render to denoise: render a frame first (F12)")
            return {"CANCELLED"}
        settings = scene.render.image_settings
        saved = (settings.file_format, settings.color_depth)
        old = bpy.data.images.get("kpcn Denoised")
        # The files live in a private folder removed whatever happens: the result is packed
        # into the .blend, so nothing is left in /tmp.
        with tempfile.TemporaryDirectory(prefix="kpcn-blender-") as folder:
            source, target = os.path.join(folder, "render.exr"), os.path.join(folder, "denoised.exr")
            try:
                settings.file_format, settings.color_depth = "OPEN_EXR_MULTILAYER", "32"
                result.save_render(source, scene=scene)
                denoise_file(source, target, output_layer(scene), **_settings_of(context))
            except (KpcnError, RuntimeError) as e:
                # RuntimeError: save_render found no render to save.
                self.report({"ERROR"}, f"kpcn: {e}")
                return {"CANCELLED"}
            finally:
                settings.file_format, settings.color_depth = saved
            if old is not None:
                bpy.data.images.remove(old)
            image = bpy.data.images.load(target)
            image.name = "kpcn Denoised"
            image.pack()
        self.report({"INFO"}, f"kpcn: denoised into the image \"kpcn Denoised\", pass {output_layer(scene)}")
        return {"FINISHED"}


@bpy.app.handlers.persistent
def _on_render_write(scene, *_):
    if not scene.kpcn.auto:
        return
    if scene.render.image_settings.file_format != "OPEN_EXR_MULTILAYER":
        print("kpcn: frames are not multilayer EXRs (Output > File Format); not denoising")
        return
    path = bpy.path.abspath(scene.render.frame_path(frame=scene.frame_current))
    try:
        denoise_file(path, path, output_layer(scene), **_settings_of(bpy.context))
        print(f"kpcn: denoised {path} ({output_layer(scene)})")
    except KpcnError as e:
        # A render handler cannot fail the render; say it loudly instead.
        print(f"kpcn: ERROR: {path}: {e}")


class KPCN_PT_output(bpy.types.Panel):
    bl_label = "kpcn"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "output"

    def draw(self, context):
        self.layout.prop(context.scene.kpcn, "auto")
        self.layout.operator(KPCN_OT_enable_passes.bl_idname)
        self.layout.operator(KPCN_OT_denoise_render.bl_idname)


def _menu(self, context):
    self.layout.operator(KPCN_OT_denoise_render.bl_idname)


classes = (KpcnPreferences, KpcnSettings, KPCN_OT_enable_passes, KPCN_OT_denoise_render, KPCN_PT_output)


def register():
    for c in classes:
        bpy.utils.register_class(c)
    bpy.types.Scene.kpcn = bpy.props.PointerProperty(type=KpcnSettings)
    bpy.types.TOPBAR_MT_render.append(_menu)
    bpy.app.handlers.render_write.append(_on_render_write)


def unregister():
    bpy.app.handlers.render_write.remove(_on_render_write)
    bpy.types.TOPBAR_MT_render.remove(_menu)
    del bpy.types.Scene.kpcn
    for c in reversed(classes):
        bpy.utils.unregister_class(c)
