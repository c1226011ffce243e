"""Every written file re-read; USD validation, Khronos glTF validator, OBJ/MTL references, CLI errors."""
from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest

from srvol.cli import main as srvol_main
from srvol.export.asset import load_asset
from srvol.export.gltf import read_glb
from srvol.images import read_exr, read_png



def test_report_and_manifest(sphere_asset):
    root, report = sphere_asset
    assert report.unfilled_fraction == 0.0
    assert set(report.seconds) >= {"extract", "simplify", "unwrap", "bake", "write", "total"}
    meta = json.loads((root / "asset.json").read_text())
    assert meta["format"] == "srvol-asset/1"
    for rel in [meta["mesh"], *meta["textures"].values(), *meta["files"].values()]:
        assert (root / rel).is_file(), rel
    assert not any(p.name.startswith(".") for p in root.parent.iterdir())  # no temporary left behind


def test_raw_exrs_and_mesh_round_trip(sphere_asset):
    root, _ = sphere_asset
    asset = load_asset(root)
    assert asset.mesh.uv is not None and asset.mesh.normals is not None
    r = read_exr(root / "raw" / "roughness.exr")
    np.testing.assert_allclose(r, np.sqrt(asset.textures.alpha), atol=1e-6)
    assert asset.textures.albedo.shape == (128, 128, 3)
    # 8-bit sRGB PNG decodes to the linear EXR within quantisation.
    png = read_png(root / "textures" / "albedo.png", srgb=True)
    np.testing.assert_allclose(png, asset.textures.albedo, atol=0.01)
    png16 = read_png(root / "textures" / "roughness.png", srgb=False)
    np.testing.assert_allclose(png16[..., 0], r[..., 0], atol=1e-4)


def test_usd_round_trip_and_validation(sphere_asset):
    from pxr import Usd, UsdGeom, UsdShade

    from srvol.export.usd import validate

    root, _ = sphere_asset
    mesh = load_asset(root).mesh
    for name in ("model.usda", "model.usdc", "model.usdz"):
        assert validate(root / name) == [], name
        stage = Usd.Stage.Open(str(root / name))
        assert UsdGeom.GetStageUpAxis(stage) == "Z" and UsdGeom.GetStageMetersPerUnit(stage) == 1.0
        geo = UsdGeom.Mesh(stage.GetPrimAtPath("/Asset/Geom/mesh"))
        np.testing.assert_allclose(np.asarray(geo.GetPointsAttr().Get()), mesh.vertices, atol=1e-6)
        st = UsdGeom.PrimvarsAPI(geo).GetPrimvar("st")
        assert st.GetInterpolation() == "faceVarying" and st.IsIndexed()
        np.testing.assert_allclose(np.asarray(st.ComputeFlattened()), mesh.uv[mesh.faces.reshape(-1)], atol=1e-6)
        surf = UsdShade.Shader(stage.GetPrimAtPath("/Asset/Looks/Material/PreviewSurface"))
        assert surf.GetInput("useSpecularWorkflow").Get() == 1
        rough_tex = UsdShade.Shader(stage.GetPrimAtPath("/Asset/Looks/Material/roughnessTexture"))
        assert rough_tex.GetInput("file").Get().path == "./raw/roughness.exr"  # r, never alpha
        assert rough_tex.GetInput("sourceColorSpace").Get() == "raw"
        assert rough_tex.GetInput("wrapS").Get() == "clamp"


def test_usd_validator_catches_missing_stage_metadata(tmp_path):
    """The validation the writer passes is not vacuous: a stage without metersPerUnit fails it."""
    from pxr import Usd, UsdGeom

    from srvol.export.usd import validate

    stage = Usd.Stage.CreateNew(str(tmp_path / "bare.usda"))
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/Root").GetPrim())
    stage.GetRootLayer().Save()
    assert validate(tmp_path / "bare.usda") != []


def test_glb_round_trip(sphere_asset):
    root, _ = sphere_asset
    doc, data = read_glb(root / "model.glb")
    mat = doc["materials"][0]
    assert set(doc["extensionsUsed"]) == {"KHR_materials_specular", "KHR_materials_ior"}
    spec_ref = float(load_asset(root).textures.specular.max())
    ior = mat["extensions"]["KHR_materials_ior"]["ior"]
    assert ((ior - 1) / (ior + 1)) ** 2 == pytest.approx(spec_ref, rel=1e-5)
    acc = doc["accessors"][doc["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"]]
    view = doc["bufferViews"][acc["bufferView"]]
    tc = np.frombuffer(data, np.float32, acc["count"] * 2, view["byteOffset"]).reshape(-1, 2)
    uv = load_asset(root).mesh.uv
    np.testing.assert_allclose(tc, np.stack([uv[:, 0], 1 - uv[:, 1]], -1), atol=1e-7)  # v flipped
    # metallicRoughness: G = r, B = 0 (8-bit)
    mr_img = doc["images"][doc["textures"][mat["pbrMetallicRoughness"]["metallicRoughnessTexture"]["index"]]["source"]]
    v = doc["bufferViews"][mr_img["bufferView"]]
    import io

    from PIL import Image

    mr = np.asarray(Image.open(io.BytesIO(data[v["byteOffset"]:v["byteOffset"] + v["byteLength"]]))) / 255.0
    r = read_exr(root / "raw" / "roughness.exr")[..., 0]
    np.testing.assert_allclose(mr[..., 1], r, atol=1 / 255 + 1e-6)
    assert mr[..., 2].max() == 0.0
    gltf = json.loads((root / "model.gltf").read_text())
    assert (root / gltf["buffers"][0]["uri"]).stat().st_size == gltf["buffers"][0]["byteLength"]


def test_glb_read_by_trimesh(sphere_asset):
    import trimesh

    root, _ = sphere_asset
    scene = trimesh.load(root / "model.glb")
    geom = next(iter(scene.geometry.values()))
    assert len(geom.faces) == len(load_asset(root).mesh.faces)


def test_khronos_gltf_validator_no_errors(sphere_asset, gltf_validator):
    script = gltf_validator
    root, _ = sphere_asset
    out = subprocess.run(["node", str(script), str(root / "model.glb")], capture_output=True, text=True, check=True)
    issues = json.loads(out.stdout)
    assert issues["numErrors"] == 0, issues["messages"]
    # The only warning allowed: a normal map without TANGENT (viewers generate MikkTSpace tangents).
    assert {m["code"] for m in issues["messages"] if m["severity"] <= 1} <= {"MESH_PRIMITIVE_GENERATED_TANGENT_SPACE"}


def test_obj_mtl_references_resolve(sphere_asset):
    import trimesh

    root, _ = sphere_asset
    obj = (root / "model.obj").read_text()
    assert "mtllib model.mtl" in obj and "usemtl srvol_material" in obj
    mtl = (root / "model.mtl").read_text().splitlines()
    maps = {ln.split()[0]: ln.split()[1] for ln in mtl if ln.split() and ln.split()[0] in ("map_Kd", "map_Ks", "map_Pr", "norm")}
    assert set(maps) == {"map_Kd", "map_Ks", "map_Pr", "norm"}
    for rel in maps.values():
        assert (root / rel).is_file(), rel
    m = trimesh.load(root / "model.obj", process=False)
    assert len(m.faces) == len(load_asset(root).mesh.faces)
    assert m.visual.material.image is not None  # map_Kd found and loaded


def test_cli_refuses_existing_output_and_empty_sdf(tmp_path, capsys, monkeypatch):
    out = tmp_path / "asset"
    out.mkdir()
    (out / "keep.txt").write_text("x")
    assert srvol_main(["export", "--builtin", "bumpy", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "already exists (use --force" in err[0]
    assert (out / "keep.txt").read_text() == "x"

    import srvol.export.cli as cli

    monkeypatch.setattr(cli, "_builtin_fields", lambda name: (lambda x: x.norm(dim=-1) + 1.0, None))
    empty = tmp_path / "empty"
    assert srvol_main(["export", "--builtin", "bumpy", "--out", str(empty), "--resolution", "32"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["srvol: error: the SDF has no surface inside the unit sphere"]
    assert not empty.exists() and not any(p.name.startswith(".empty") for p in tmp_path.iterdir())


def test_cli_unreadable_run(tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    (run / "model.pt").write_bytes(b"not a checkpoint")
    (run / "config.json").write_text("{")
    assert srvol_main(["export", str(run), "--out", str(tmp_path / "a")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("srvol: error:")
