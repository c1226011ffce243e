"""USD writer: .usda / .usdc and .usdz (DESIGN.md section 6).

* Stage metadata: ``upAxis = "Z"`` (the scene frame is +z up; no rotation is
  applied), ``metersPerUnit = 1``, default prim ``/Asset`` (kind component).
* Mesh: vertex normals, face-varying ``primvars:st`` with indices (uv per
  vertex, so indices = faceVertexIndices), extent.
* Material: UsdPreviewSurface with ``diffuseColor`` (albedo), ``roughness`` (= r,
  never alpha), ``useSpecularWorkflow = 1`` + ``specularColor`` (= F0), each read
  by a UsdUVTexture from the lossless float EXRs in raw/ with
  ``sourceColorSpace = raw`` (linear data), explicit ``wrapS/wrapT = clamp``
  (charts never wrap), a ``UsdPrimvarReader_float2`` for ``st``, and relative
  ``./raw/...`` paths. The optional normal map is an 8-bit PNG with scale 2 and
  bias -1, as UsdPreviewSurface requires.

Blender's USD importer maps ``specularColor`` to Specular Tint and ignores
``useSpecularWorkflow``; srvol.export.blender fixes that after import.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from srvol.export.textures import TextureFiles
from srvol.export.types import Mesh


def _texture(stage, material_path: str, name: str, file: str, st_output, fallback):
    from pxr import Sdf, UsdShade

    tex = UsdShade.Shader.Define(stage, f"{material_path}/{name}")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(f"./{file}")
    tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("raw")
    tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("clamp")
    tex.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set("clamp")
    tex.CreateInput("fallback", Sdf.ValueTypeNames.Float4).Set(fallback)
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(st_output)
    return tex


def build_stage(stage, mesh: Mesh, files: TextureFiles) -> None:
    """Author the asset into an empty ``stage``."""
    from pxr import Gf, Kind, Sdf, Usd, UsdGeom, UsdShade, Vt

    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    root = UsdGeom.Xform.Define(stage, "/Asset")
    stage.SetDefaultPrim(root.GetPrim())
    Usd.ModelAPI(root.GetPrim()).SetKind(Kind.Tokens.component)

    geo = UsdGeom.Mesh.Define(stage, "/Asset/Geom/mesh")
    v = mesh.vertices.astype(np.float32)
    idx = mesh.faces.reshape(-1).astype(np.int32)
    geo.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(v))
    geo.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(mesh.faces), 3, dtype=np.int32)))
    geo.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(idx))
    geo.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, v.min(0))), Gf.Vec3f(*map(float, v.max(0)))]))
    geo.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    geo.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
    if mesh.normals is not None:
        geo.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(mesh.normals.astype(np.float32)))
        geo.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    st = UsdGeom.PrimvarsAPI(geo).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                UsdGeom.Tokens.faceVarying)
    st.Set(Vt.Vec2fArray.FromNumpy(mesh.uv.astype(np.float32)))
    st.SetIndices(Vt.IntArray.FromNumpy(idx))

    mpath = "/Asset/Looks/Material"
    material = UsdShade.Material.Define(stage, mpath)
    reader = UsdShade.Shader.Define(stage, f"{mpath}/stReader")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
    st_out = reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)

    surface = UsdShade.Shader.Define(stage, f"{mpath}/PreviewSurface")
    surface.CreateIdAttr("UsdPreviewSurface")
    surface.CreateInput("useSpecularWorkflow", Sdf.ValueTypeNames.Int).Set(1)
    surface.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(0.0)
    surface.CreateInput("opacity", Sdf.ValueTypeNames.Float).Set(1.0)
    albedo = _texture(stage, mpath, "albedoTexture", files.albedo_exr, st_out, Gf.Vec4f(0.5, 0.5, 0.5, 1))
    rough = _texture(stage, mpath, "roughnessTexture", files.roughness_exr, st_out, Gf.Vec4f(0.5, 0.5, 0.5, 1))
    spec = _texture(stage, mpath, "specularTexture", files.specular_exr, st_out, Gf.Vec4f(0.04, 0.04, 0.04, 1))
    surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(
        albedo.CreateOutput("rgb", Sdf.ValueTypeNames.Float3))
    surface.CreateInput("roughness", Sdf.ValueTypeNames.Float).ConnectToSource(
        rough.CreateOutput("r", Sdf.ValueTypeNames.Float))
    surface.CreateInput("specularColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(
        spec.CreateOutput("rgb", Sdf.ValueTypeNames.Float3))
    if files.normal_png is not None:
        nrm = _texture(stage, mpath, "normalTexture", files.normal_png, st_out, Gf.Vec4f(0, 0, 1, 1))
        nrm.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(2, 2, 2, 1))
        nrm.CreateInput("bias", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(-1, -1, -1, 0))
        surface.CreateInput("normal", Sdf.ValueTypeNames.Normal3f).ConnectToSource(
            nrm.CreateOutput("rgb", Sdf.ValueTypeNames.Float3))
    material.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    UsdShade.MaterialBindingAPI.Apply(geo.GetPrim()).Bind(material)


def write_usd(path: Path, mesh: Mesh, files: TextureFiles) -> None:
    """Write ``path`` (.usda or .usdc) in the asset folder root (texture paths are relative to it)."""
    from pxr import Usd

    stage = Usd.Stage.CreateNew(str(path))
    build_stage(stage, mesh, files)
    stage.GetRootLayer().Save()


def write_usdz(path: Path, mesh: Mesh, files: TextureFiles) -> None:
    """A .usdz package of a .usdc layer and its textures (written beside, then packaged)."""
    from pxr import UsdUtils

    layer = path.with_name(f".{path.stem}.pkg.usdc")
    write_usd(layer, mesh, files)
    try:
        if not UsdUtils.CreateNewUsdzPackage(str(layer), str(path)):
            raise RuntimeError(f"could not package {path}")
    finally:
        layer.unlink(missing_ok=True)


def validate(path: Path) -> list[str]:
    """Messages of every error found by all registered USD validators (empty = clean)."""
    from pxr import Usd, UsdValidation

    stage = Usd.Stage.Open(str(path))
    ctx = UsdValidation.ValidationContext(UsdValidation.ValidationRegistry().GetOrLoadAllValidators())
    errors = ctx.Validate(stage)
    return [f"{e.GetValidator().GetMetadata().name if e.GetValidator() else '?'}: {e.GetMessage()}"
            for e in errors if e.GetType() == UsdValidation.ValidationErrorType.Error]
