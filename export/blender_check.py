"""``python -m srvol.export.blender_check ASSET_DIR --out render.png``: import an exported asset into
Blender (bpy), fix and check its material wiring, and render it with Cycles under a point light.

Runs only as its own process (see srvol.export.blender). Never imports trimesh's embree module.
Writes a JSON report: per material, the image linked into Base Color and its colour space, the
roughness image, specular (tint, IOR, IOR level) and the effective F0 Blender will use.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path


def _effective_f0(ior: float, level: float, tint_scale: float) -> float:
    return ((ior - 1.0) / (ior + 1.0)) ** 2 * 2.0 * level * tint_scale


def _principled(mat):
    return next(n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")


def _linked_image(sock):
    """The image node feeding ``sock`` (through Separate Color / Vector Math), or None."""
    seen = 0
    while sock.is_linked and seen < 4:
        node = sock.links[0].from_node
        if node.bl_idname == "ShaderNodeTexImage":
            return node
        sock = next((s for s in node.inputs if s.is_linked), None)
        if sock is None:
            return None
        seen += 1
    return None


def fix_usd_specular(mat, f0_ref: float) -> None:
    """Specular Tint = texture / f0_ref, IOR from f0_ref, single-scatter GGX (see srvol.export.blender)."""
    p = _principled(mat)
    tint = p.inputs["Specular Tint"]
    ior = (1.0 + math.sqrt(f0_ref)) / (1.0 - math.sqrt(f0_ref))
    if tint.is_linked:
        src = tint.links[0].from_socket
        scale = mat.node_tree.nodes.new("ShaderNodeVectorMath")
        scale.name = "srvol F0 scale"
        scale.operation = "SCALE"
        scale.inputs["Scale"].default_value = 1.0 / f0_ref
        mat.node_tree.links.new(src, scale.inputs[0])
        mat.node_tree.links.new(scale.outputs["Vector"], tint)
    p.inputs["IOR"].default_value = ior
    p.inputs["Specular IOR Level"].default_value = 0.5
    p.distribution = "GGX"


def wiring(mat) -> dict:
    p = _principled(mat)
    base = _linked_image(p.inputs["Base Color"])
    rough = _linked_image(p.inputs["Roughness"])
    tint = p.inputs["Specular Tint"]
    spec_img = _linked_image(tint)
    scale_node = tint.links[0].from_node if tint.is_linked else None
    tint_scale = (scale_node.inputs["Scale"].default_value
                  if scale_node is not None and scale_node.bl_idname == "ShaderNodeVectorMath" else 1.0)
    ior = p.inputs["IOR"].default_value
    level = p.inputs["Specular IOR Level"].default_value
    return {
        "material": mat.name,
        "base_color_image": (base.image.filepath or base.image.name) if base else None,
        "base_color_colorspace": base.image.colorspace_settings.name if base else None,
        "roughness_image": (rough.image.filepath or rough.image.name) if rough else None,
        "roughness_colorspace": rough.image.colorspace_settings.name if rough else None,
        "specular_image": (spec_img.image.filepath or spec_img.image.name) if spec_img else None,
        "specular_tint_scale": tint_scale,
        "ior": ior,
        "specular_ior_level": level,
        "f0_per_unit_specular_texel": _effective_f0(ior, level, tint_scale),
        "distribution": p.distribution,
    }


def image_mean(node, channel: int = 0) -> float:
    """Mean of one channel of an image node's pixels (as Blender decodes them)."""
    img = node.image
    px = list(img.pixels[:])
    c = img.channels
    vals = px[min(channel, c - 1)::c]
    return sum(vals) / max(len(vals), 1)


def setup_scene(view: dict):
    import bpy
    from mathutils import Vector

    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = int(view["samples"])
    scene.cycles.use_denoising = False
    scene.cycles.max_bounces = 0  # direct light only, as srvol's point-light shading
    scene.cycles.filter_width = float(view.get("filter_width", 1.5))
    scene.render.resolution_x, scene.render.resolution_y = int(view["width"]), int(view["height"])
    scene.render.resolution_percentage = 100
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    scene.render.film_transparent = False
    world = bpy.data.worlds.new("black")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
    scene.world = world

    cam_data = bpy.data.cameras.new("camera")
    cam_data.sensor_fit = "HORIZONTAL"
    cam_data.angle = math.radians(view["fov_deg"])
    cam = bpy.data.objects.new("camera", cam_data)
    scene.collection.objects.link(cam)
    eye, target = Vector(view["eye"]), Vector(view["target"])
    cam.location = eye
    cam.rotation_euler = (target - eye).to_track_quat("-Z", "Y").to_euler()
    scene.camera = cam

    light_data = bpy.data.lights.new("point", type="POINT")
    light_data.energy = 4.0 * math.pi * float(view["intensity"])
    light_data.shadow_soft_size = 0.0
    if hasattr(light_data, "use_soft_falloff"):
        light_data.use_soft_falloff = False
    light = bpy.data.objects.new("point", light_data)
    light.location = Vector(view["light"])
    scene.collection.objects.link(light)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m srvol.export.blender_check")
    ap.add_argument("asset", type=Path)
    ap.add_argument("--out", type=Path, required=True, help="render PNG (sRGB)")
    ap.add_argument("--exr", type=Path, help="also save the linear render as EXR")
    ap.add_argument("--blend", type=Path, help="also save a ready .blend")
    ap.add_argument("--report", type=Path, required=True)
    ap.add_argument("--source", choices=("usd", "glb"), default="usd")
    ap.add_argument("--view", default="{}", help="BlenderView fields as JSON")
    ap.add_argument("--no-render", action="store_true", help="check and save only (for --blend)")
    args = ap.parse_args(argv)
    import bpy

    from srvol.export.blender import BlenderView

    view = {**BlenderView().__dict__, **json.loads(args.view)}
    bpy.ops.wm.read_factory_settings(use_empty=True)
    root = args.asset.resolve()
    meta = json.loads((root / "asset.json").read_text()) if (root / "asset.json").is_file() else {}
    files = meta.get("files", {})
    if args.source == "usd":
        usd = next((root / n for n in (files.get("usd"), files.get("usdc"), "model.usda", "model.usdc", ".blend_source.usda")
                    if n and (root / n).is_file()), None)
        if usd is None:
            print("no USD file in the asset", file=sys.stderr)
            return 2
        bpy.ops.wm.usd_import(filepath=str(usd))
        from srvol.images import read_exr  # numpy + OpenEXR only, no embree

        f0_ref = max(float(read_exr(root / "raw" / "specular.exr").max()), 0.04)  # textures.specular_reference
        for mat in bpy.data.materials:
            if mat.node_tree is not None and any(n.bl_idname == "ShaderNodeBsdfPrincipled" for n in mat.node_tree.nodes):
                fix_usd_specular(mat, f0_ref)
    else:
        bpy.ops.import_scene.gltf(filepath=str(root / files.get("glb", "model.glb")))
        for mat in bpy.data.materials:
            if mat.node_tree is not None and any(n.bl_idname == "ShaderNodeBsdfPrincipled" for n in mat.node_tree.nodes):
                _principled(mat).distribution = "GGX"
    mats = [m for m in bpy.data.materials
            if m.node_tree is not None and any(n.bl_idname == "ShaderNodeBsdfPrincipled" for n in m.node_tree.nodes)]
    report = {"source": args.source, "materials": []}
    for m in mats:
        w = wiring(m)
        p = _principled(m)
        rough = _linked_image(p.inputs["Roughness"])
        sock = p.inputs["Roughness"]
        channel = {"Red": 0, "Green": 1, "Blue": 2}.get(sock.links[0].from_socket.name, 0) if sock.is_linked else 0
        w["roughness_image_mean"] = image_mean(rough, channel) if rough else None
        report["materials"].append(w)
    setup_scene(view)
    scene = bpy.context.scene
    if args.exr is not None and not args.no_render:
        scene.render.image_settings.file_format = "OPEN_EXR"
        scene.render.image_settings.color_depth = "32"
        scene.render.filepath = str(args.exr.resolve())
        bpy.ops.render.render(write_still=True)
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_depth = "8"
    scene.render.filepath = str(args.out.resolve())
    if not args.no_render:
        bpy.ops.render.render(write_still=True)
    if args.blend is not None:
        # Textures stay in the asset folder, referenced relative to the .blend saved beside them.
        bpy.context.preferences.filepaths.save_version = 0  # no model.blend1 backup
        bpy.ops.wm.save_as_mainfile(filepath=str(args.blend.resolve()), relative_remap=True)
        bpy.ops.file.make_paths_relative()
        bpy.ops.wm.save_mainfile()
    args.report.write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
