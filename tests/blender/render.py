# Run by tests/plugins.rs inside Blender, headless:
#   BLENDER_USER_SCRIPTS=S KPCN_LIBRARY=LIB blender -b --factory-startup --python render.py -- OUT
# with the add-on at S/addons/kpcn_denoise.py. Renders the factory scene with Cycles at 4 spp
# as a one-frame animation (the add-on denoises OUT/frame_0001.exr in place as it is
# written), then runs "Denoise Last Render" on a plain render and copies its image to OUT/operator.exr,
# and checks that a library error reaches Blender's report.
import os
import sys

import addon_utils
import bpy

out = sys.argv[sys.argv.index("--") + 1]
addon_utils.enable("kpcn_denoise", default_set=True, handle_error=None)
assert bpy.context.preferences.addons.get("kpcn_denoise"), "the add-on is enabled"

scene = bpy.context.scene
scene.render.engine = "CYCLES"
scene.cycles.device = "CPU"
scene.cycles.samples = 4
scene.cycles.use_denoising = False
scene.cycles.seed = 1
scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 64, 48, 100
scene.render.image_settings.file_format = "OPEN_EXR_MULTILAYER"
scene.render.image_settings.color_depth = "32"
scene.frame_start = scene.frame_end = 1
scene.render.filepath = out + "/frame_####"
bpy.ops.kpcn.enable_passes()
scene.kpcn.auto = True

bpy.ops.render.render(animation=True)
# A plain render leaves "Render Result" filled for the operator.
bpy.ops.render.render()
assert bpy.ops.kpcn.denoise_render() == {"FINISHED"}
image = bpy.data.images["kpcn Denoised"]
# The result is packed into the .blend, and the add-on's temporary folder is gone.
assert image.packed_file is not None, "the denoised image is packed"
assert not os.path.exists(os.path.dirname(bpy.path.abspath(image.filepath))), image.filepath
with open(out + "/operator.exr", "wb") as f:
    f.write(image.packed_file.data)
# The compositor's Image node lists the new layer as a pass of the view layer.
scene.use_nodes = True
node = scene.node_tree.nodes.new("CompositorNodeImage")
node.image = bpy.data.images.load(out + "/frame_0001.exr")
node.image.reload()
node.layer = node.layer  # refreshes the outputs from the file
outputs = [o.name for o in node.outputs]
assert "Denoised" in outputs, outputs
# A library error is Blender's own error report (bpy.ops raises it as RuntimeError).
prefs = bpy.context.preferences.addons["kpcn_denoise"].preferences
prefs.model = "/nonexistent/m.safetensors"
try:
    bpy.ops.kpcn.denoise_render()
    raise AssertionError("a missing model file was not reported")
except RuntimeError as e:
    assert "kpcn:" in str(e) and "/nonexistent/m.safetensors" in str(e), e
prefs.model = ""
print("kpcn-test: done")
