"""Point-light rendering with shadows, of the neural fields and of an exported asset.

Two surfaces, one image formation. A :class:`FieldScene` sphere-traces an SDF (the trained
model, or an analytic stand-in); an :class:`AssetScene` ray-casts an exported triangle mesh with
embree and reads its textures bilinearly. Both hand their hits to :func:`render_scene`, which
applies the :class:`~srvol.relight.edits.MaterialEdit` and calls :func:`srvol.brdf.shade` --
the BRDF used in training -- with the general light direction (l != v) and a shadow test
towards the light.

Conventions are those of :mod:`srvol.types`: scene frame (object in the unit sphere), OpenCV
cameras, linear RGB, light of radiant intensity I (W/sr). A pixel is the mean of ``ss x ss``
rays on a regular sub-pixel grid (as the ground-truth renderer of :mod:`srvol.synth.render`).
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Protocol

import numpy as np
import torch
from torch import Tensor

from srvol.brdf import shade
from srvol.errors import SrvolError
from srvol.geometry import MeshRayCaster, ray_sphere, sdf_normals
from srvol.export.types import Asset
from srvol.psf import box_offsets
from srvol.relight.edits import MaterialEdit, sample_texture
from srvol.types import ALPHA_MIN, Camera, MaterialFn, PointLight, Rays, SdfFn, SurfaceMaterial

RAY_CHUNK = 1 << 19
"""Rays per batch in :func:`render_scene`: a whole 640x480 frame in one batch, so that sphere tracing
makes few, large SDF calls (each call of a trained model has a fixed cost)."""


@dataclass(frozen=True)
class SurfaceHits:
    """The rays of a batch that hit the surface (M of them).

    index (M,) long: which rays of the batch; t (M,) distance along the ray; points (M, 3);
    normals (M, 3) unit shading normals, facing the side the ray came from;
    uv (M, 2) texture coordinates (origin bottom-left) or None where the surface has none.
    """

    index: Tensor
    t: Tensor
    points: Tensor
    normals: Tensor
    uv: Tensor | None = None


class RelightScene(Protocol):
    """A surface that can be ray-cast, shadow-tested and asked for its material."""

    def intersect(self, rays: Rays) -> SurfaceHits:
        ...

    def material_at(self, hits: SurfaceHits) -> SurfaceMaterial:
        ...

    def light_visibility(self, points: Tensor, normals: Tensor, light: PointLight) -> Tensor:
        """(M,) 1 where the segment from each point to the light is free, else 0."""
        ...

    def contains(self, point: Tensor) -> bool:
        """Whether a scene point (3,) lies inside the object."""
        ...


@dataclass(frozen=True)
class RelitImage:
    """A rendered image, numpy float32.

    rgb (H, W, 3) linear radiance (0 on background); mask (H, W) coverage in [0, 1] (fraction of
    sub-pixel rays that hit); normal (H, W, 3) mean world normal of the hits, re-normalised (zero
    on background); depth (H, W) mean distance along the ray of the hits (zero on background).
    """

    rgb: np.ndarray
    mask: np.ndarray
    normal: np.ndarray
    depth: np.ndarray


# ----------------------------------------------------------------------------- image formation

def shade_hits(scene: RelightScene, hits: SurfaceHits, rays: Rays, light: PointLight,
               edit: MaterialEdit | None, shadows: bool) -> Tensor:
    """(M, 3) radiance towards the camera at the hits of ``rays`` under ``light`` (``edit`` None = as is)."""
    material = scene.material_at(hits)
    if edit is not None:
        material = edit.apply(material, hits.points, hits.uv)
    visibility = None
    if shadows:  # points facing away from the light are black anyway: no shadow ray for them
        facing = ((light.position.to(hits.points) - hits.points) * hits.normals).sum(-1) > 0
        visibility = torch.zeros(hits.points.shape[0], dtype=hits.points.dtype)
        idx = torch.nonzero(facing).squeeze(-1)
        if idx.numel():
            visibility[idx] = scene.light_visibility(hits.points[idx], hits.normals[idx], light).to(visibility)
    view_dir = -rays.directions[hits.index]
    return shade(material, hits.normals, hits.points, view_dir, light, visibility)


def render_scene(scene: RelightScene, camera: Camera, light: PointLight, edit: MaterialEdit | None = None,
                 shadows: bool = True, ss: int = 1, chunk: int = RAY_CHUNK) -> RelitImage:
    """Render ``camera``'s image of ``scene`` under ``light``, each pixel the mean of ss x ss rays.

    ``edit`` None renders the material as it is; ``chunk`` rays are traced per batch.
    """
    cam = camera.to("cpu", torch.float32)
    lit = light.to("cpu", torch.float32)
    H, W = cam.height, cam.width
    centers = cam.pixel_centers()
    offsets = box_offsets(ss)
    rgb = torch.zeros(H * W, 3)
    cov = torch.zeros(H * W)
    nsum = torch.zeros(H * W, 3)
    dsum = torch.zeros(H * W)
    with torch.no_grad():
        for off in offsets:
            for s in range(0, H * W, chunk):
                rays = cam.rays_at(centers[s:s + chunk] + off)
                hits = scene.intersect(rays)
                if hits.index.numel() == 0:
                    continue
                idx = hits.index + s
                rgb[idx] += shade_hits(scene, hits, rays, lit, edit, shadows).float()
                cov[idx] += 1
                nsum[idx] += hits.normals.float()
                dsum[idx] += hits.t.float()
    n_rays = len(offsets)
    depth = torch.where(cov > 0, dsum / cov.clamp_min(1), torch.zeros_like(dsum))
    normal = nsum / nsum.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    return RelitImage(rgb=(rgb / n_rays).reshape(H, W, 3).numpy(), mask=(cov / n_rays).reshape(H, W).numpy(),
                      normal=normal.reshape(H, W, 3).numpy(), depth=depth.reshape(H, W).numpy())


# ----------------------------------------------------------------------------- neural path (SDF)

@dataclass(frozen=True)
class TraceOptions:
    """Sphere tracing of an SDF.

    bound:      radius of the origin-centred sphere holding the object (scene frame: 1).
    step_scale: fraction of the SDF value stepped each iteration; < 1 for fields that may
                over-estimate the distance (a trained network; an analytic SDF with Lipschitz
                constant L needs 1 / L).
    max_steps:  iterations before a ray is given up (a ray still within 10 eps then counts as a hit).
    eps:        a ray has hit when the SDF falls below eps.
    shadow_bias: shadow rays start this far off the surface along the normal.
    tail_rays:  once no more than this many rays are still marching (grazing rays creeping along
                a surface), they are finished together by dense sampling instead: every SDF
                call of a trained model costs a fixed overhead (~0.1 s for a grid model on
                2 cores), so a hundred steps of a few rays each would dominate the frame.
    tail_samples: samples per remaining ray in that dense pass (then 8 bisection steps).
    tail_after: the dense pass starts no earlier than this many sphere-tracing steps.
    """

    bound: float = 1.0
    step_scale: float = 0.9
    max_steps: int = 192
    eps: float = 1e-4
    shadow_bias: float = 2e-3
    tail_rays: int = 2048
    tail_samples: int = 64
    tail_after: int = 48


def sphere_trace(sdf_fn: SdfFn, origins: Tensor, directions: Tensor, t_near: Tensor, t_far: Tensor,
                 opts: TraceOptions) -> tuple[Tensor, Tensor]:
    """March rays from ``t_near`` until the SDF falls below ``opts.eps`` or ``t_far`` is passed.

    Returns hit (N,) bool and t (N,) (the hit distance, moved onto the surface by the last SDF
    value; undefined where there is no hit). Only live rays are evaluated: the active set is
    compacted every step; the last ``opts.tail_rays`` are finished by :func:`first_crossing`.
    """
    n = origins.shape[0]
    hit = torch.zeros(n, dtype=torch.bool)
    t = t_far.clone()
    idx = torch.nonzero(t_near < t_far).squeeze(-1)
    oa, da, ta, fa = origins[idx], directions[idx], t_near[idx], t_far[idx]
    for step in range(opts.max_steps):
        if idx.numel() == 0 or (step >= opts.tail_after and idx.numel() <= opts.tail_rays):
            break
        d = sdf_fn(oa + ta[:, None] * da).reshape(-1).to(ta.dtype)
        done = d < opts.eps
        if done.any():
            hit[idx[done]] = True
            t[idx[done]] = ta[done] + d[done]
        ta = ta + d * opts.step_scale
        keep = ~done & (ta < fa)
        idx, oa, da, ta, fa = idx[keep], oa[keep], da[keep], ta[keep], fa[keep]
    if idx.numel():
        tail_hit, tail_t = first_crossing(sdf_fn, oa, da, ta, fa, opts)
        hit[idx[tail_hit]] = True
        t[idx[tail_hit]] = tail_t[tail_hit]
    return hit, t


def first_crossing(sdf_fn: SdfFn, origins: Tensor, directions: Tensor, t0: Tensor, t1: Tensor,
                   opts: TraceOptions, rounds: int = 3, bisections: int = 10) -> tuple[Tensor, Tensor]:
    """The first point of each ray in [t0, t1] where the SDF falls below eps, with few SDF calls.

    Each round samples every open ray at ``opts.tail_samples`` uniform points (one call). A sample
    below eps brackets a crossing. Between two samples further apart than their SDF values allow
    (``(d_i + d_i+1) * step_scale < spacing``) a crossing may hide: if that interval comes before
    the first bracket, the next round zooms into it (keeping the later bracket as a fallback).
    Brackets are then bisected together. Rays with neither are misses.
    """
    n, S = origins.shape[0], opts.tail_samples
    s = torch.linspace(0.0, 1.0, S, dtype=t0.dtype)
    hit = torch.zeros(n, dtype=torch.bool)
    lo_b, hi_b = t0.clone(), t0.clone()  # the bracket of each hit ray
    fb = torch.zeros(n, dtype=torch.bool)  # a later bracket to fall back on
    fb_lo, fb_hi = t0.clone(), t0.clone()
    open_ = torch.arange(n)
    lo, hi = t0.clone(), t1.clone()
    for r in range(rounds):
        if open_.numel() == 0:
            break
        ts = lo[open_, None] + (hi - lo)[open_, None] * s[None, :]
        o, d = origins[open_], directions[open_]
        vals = sdf_fn((o[:, None, :] + ts[..., None] * d[:, None, :]).reshape(-1, 3)).reshape(-1, S).to(ts.dtype)
        below = vals < opts.eps
        has_b = below.any(dim=1)
        f = torch.where(has_b, below.to(torch.uint8).argmax(dim=1), torch.full_like(has_b, S, dtype=torch.long))
        spacing = (hi - lo)[open_] / (S - 1)
        cand = (vals[:, :-1] + vals[:, 1:]) * opts.step_scale < spacing[:, None]
        cand &= torch.arange(S - 1)[None, :] < (f - 1)[:, None]  # only intervals before the bracket
        has_c = cand.any(dim=1) & (r < rounds - 1)
        j = cand.to(torch.uint8).argmax(dim=1)
        take_b = has_b & ~has_c
        fc = f.clamp(max=S - 1)
        b_lo = ts.gather(1, (fc - 1).clamp_min(0)[:, None])[:, 0]
        b_hi = ts.gather(1, fc[:, None])[:, 0]
        rows = open_[take_b]
        hit[rows] = True
        lo_b[rows], hi_b[rows] = b_lo[take_b], b_hi[take_b]
        keep_fb = has_b & has_c
        fb[open_[keep_fb]] = True
        fb_lo[open_[keep_fb]], fb_hi[open_[keep_fb]] = b_lo[keep_fb], b_hi[keep_fb]
        zoom = open_[has_c]
        lo[zoom] = ts[has_c].gather(1, j[has_c][:, None])[:, 0]
        hi[zoom] = ts[has_c].gather(1, (j[has_c] + 1)[:, None])[:, 0]
        done_miss = open_[~has_b & ~has_c]
        use_fb = done_miss[fb[done_miss]]
        hit[use_fb] = True
        lo_b[use_fb], hi_b[use_fb] = fb_lo[use_fb], fb_hi[use_fb]
        open_ = zoom
    live = torch.nonzero(hit & (hi_b > lo_b)).squeeze(-1)
    o, d, a, b = origins[live], directions[live], lo_b[live], hi_b[live]
    for _ in range(bisections if live.numel() else 0):
        mid = 0.5 * (a + b)
        inside = sdf_fn(o + mid[:, None] * d).reshape(-1) < opts.eps
        a, b = torch.where(inside, a, mid), torch.where(inside, mid, b)
    hi_b[live] = b
    return hit, hi_b


@dataclass(frozen=True)
class FieldScene:
    """The neural path: an SDF callable and a material callable (float32 in and out)."""

    sdf_fn: SdfFn
    material_fn: MaterialFn
    options: TraceOptions = TraceOptions()

    def intersect(self, rays: Rays) -> SurfaceHits:
        o, d = rays.origins.float(), rays.directions.float()
        near, far = ray_sphere(Rays(o, d), self.options.bound)
        hit, t = sphere_trace(self.sdf_fn, o, d, near, far, self.options)
        idx = torch.nonzero(hit).squeeze(-1)
        pts = o[idx] + t[idx, None] * d[idx]
        return SurfaceHits(index=idx, t=t[idx], points=pts, normals=sdf_normals(self.sdf_fn, pts, RAY_CHUNK))

    def material_at(self, hits: SurfaceHits) -> SurfaceMaterial:
        return self.material_at_points(hits.points)

    def material_at_points(self, points: Tensor) -> SurfaceMaterial:
        m = self.material_fn(points)
        return SurfaceMaterial(albedo=m.albedo.float(), specular=m.specular.float(), alpha=m.alpha.float())

    def light_visibility(self, points: Tensor, normals: Tensor, light: PointLight) -> Tensor:
        origins = points + self.options.shadow_bias * normals
        to_light = light.position.to(origins) - origins
        dist = to_light.norm(dim=-1)
        dirs = to_light / dist[:, None].clamp_min(1e-12)
        _, exit_t = ray_sphere(Rays(origins, dirs), self.options.bound)
        far = torch.minimum(dist, exit_t)
        hit, _ = sphere_trace(self.sdf_fn, origins, dirs, torch.zeros_like(far), far, self.options)
        return (~hit).float()

    def contains(self, point: Tensor) -> bool:
        with torch.no_grad():
            return bool(self.sdf_fn(point.reshape(1, 3).float()).reshape(-1)[0] < 0)


def render_fields(sdf_fn: SdfFn, material_fn: MaterialFn, camera: Camera, light: PointLight,
                  edit: MaterialEdit | None = None, shadows: bool = True, ss: int = 1,
                  options: TraceOptions = TraceOptions()) -> RelitImage:
    """The neural path: sphere-trace ``sdf_fn``, shade with srvol's BRDF, shadow rays through the SDF."""
    return render_scene(FieldScene(sdf_fn, material_fn, options), camera, light, edit, shadows, ss)


# ----------------------------------------------------------------------------- asset path (mesh)

@dataclass(frozen=True)
class AssetScene:
    """An exported asset prepared for ray casting (embree BVH built once).

    caster: the mesh's :class:`~srvol.geometry.MeshRayCaster`; normals (V, 3) shading normals (the
    asset's, else area-weighted vertex normals), uv (V, 2) or None; textures as torch tensors
    (H, W, C) linear. ``shadow_bias`` offsets shadow rays along the geometric normal (scene units).
    With a tangent-space normal map (TextureSet.normal), shading normals are perturbed in the
    exporter's tangent frames (``tangents`` (V, 3), ``tangent_signs`` (V,)).
    """

    caster: MeshRayCaster
    normals: np.ndarray
    uv: np.ndarray | None
    albedo: Tensor
    specular: Tensor
    alpha: Tensor
    shadow_bias: float = 1e-4
    normal_map: Tensor | None = None
    tangents: np.ndarray | None = None
    tangent_signs: np.ndarray | None = None

    @staticmethod
    def build(asset: Asset, shadow_bias: float = 1e-4) -> "AssetScene":
        import trimesh

        m = asset.mesh
        tm = trimesh.Trimesh(vertices=np.asarray(m.vertices, np.float64), faces=np.asarray(m.faces, np.int64),
                             process=False)
        normals = np.asarray(m.normals, np.float64) if m.normals is not None else np.asarray(tm.vertex_normals)
        tex = asset.textures
        normal_map = tangents = signs = None
        if tex.normal is not None and m.uv is not None:
            from srvol.export.bake import tangent_frames  # the exporter's tangent convention, shared

            tangents, signs = tangent_frames(replace(m, normals=normals.astype(np.float32)))
            normal_map = torch.from_numpy(np.ascontiguousarray(tex.normal[..., :3], np.float32))
        return AssetScene(caster=MeshRayCaster.build(tm), normals=normals,
                          uv=None if m.uv is None else np.asarray(m.uv, np.float64),
                          albedo=torch.from_numpy(np.ascontiguousarray(tex.albedo[..., :3], np.float32)),
                          specular=torch.from_numpy(np.ascontiguousarray(tex.specular[..., :1], np.float32)),
                          alpha=torch.from_numpy(np.ascontiguousarray(tex.alpha[..., :1], np.float32)),
                          shadow_bias=shadow_bias, normal_map=normal_map, tangents=tangents, tangent_signs=signs)

    def intersect(self, rays: Rays) -> SurfaceHits:
        o = rays.origins.detach().double().numpy()
        d = rays.directions.detach().double().numpy()
        hits = self.caster.first_hits(o, d)
        n = self.caster.interpolate(hits, self.normals)
        uv = None if self.uv is None else self.caster.interpolate(hits, self.uv)
        if self.normal_map is not None and len(hits.ray):
            n = self._apply_normal_map(n, hits.bary, self.caster.faces[hits.face], uv)
        # shading normals on the side of the geometric face the ray sees
        fn = self.caster.face_normals[hits.face]
        front = -np.sign((fn * d[hits.ray]).sum(-1, keepdims=True))
        front[front == 0] = 1
        n = np.where(((n * fn).sum(-1, keepdims=True) * front) < 0, -n, n)
        n /= np.linalg.norm(n, axis=-1, keepdims=True).clip(1e-12)
        uv = None if uv is None else torch.from_numpy(uv).float()
        return SurfaceHits(index=torch.from_numpy(hits.ray), t=torch.from_numpy(hits.t).float(),
                           points=torch.from_numpy(hits.points).float(), normals=torch.from_numpy(n).float(), uv=uv)

    def _apply_normal_map(self, n: np.ndarray, bary: np.ndarray, f: np.ndarray, uv: np.ndarray) -> np.ndarray:
        """Perturb interpolated normals by the tangent-space normal map, in the frame the exporter
        baked it in (``srvol.export.bake``: T along +u orthogonalised against n, B = sign * n x T)."""
        n = n / np.linalg.norm(n, axis=-1, keepdims=True).clip(1e-12)
        t = np.einsum("mk,mkc->mc", bary, self.tangents[f])
        t -= (t * n).sum(-1, keepdims=True) * n
        t /= np.linalg.norm(t, axis=-1, keepdims=True).clip(1e-12)
        b = np.cross(n, t) * self.tangent_signs[f[:, 0]][:, None]
        nt = sample_texture(self.normal_map, torch.from_numpy(uv).float()).double().numpy()
        nt /= np.linalg.norm(nt, axis=-1, keepdims=True).clip(1e-12)
        return nt[:, :1] * t + nt[:, 1:2] * b + nt[:, 2:3] * n

    def material_at(self, hits: SurfaceHits) -> SurfaceMaterial:
        if hits.uv is None:
            raise SrvolError("the asset's mesh has no UVs: its textures cannot be read")
        return SurfaceMaterial(albedo=sample_texture(self.albedo, hits.uv),
                               specular=sample_texture(self.specular, hits.uv),
                               alpha=sample_texture(self.alpha, hits.uv).clamp_min(ALPHA_MIN))

    def light_visibility(self, points: Tensor, normals: Tensor, light: PointLight) -> Tensor:
        p = points.detach().double().numpy()
        n = normals.detach().double().numpy()
        lpos = light.position.detach().double().numpy()
        to_light = lpos - p
        dist = np.linalg.norm(to_light, axis=-1)
        dirs = to_light / dist[:, None].clip(1e-12)
        # offset off the surface on the light's side (shading normals may face away near the terminator)
        side = np.where((n * dirs).sum(-1, keepdims=True) >= 0, 1.0, -1.0)
        origins = p + self.shadow_bias * side * n + self.shadow_bias * dirs
        idx, _, t = self.caster.first_faces(origins, dirs)
        vis = np.ones(len(p), np.float32)
        blocked = (t > 0) & (t < dist[idx] - 2 * self.shadow_bias)
        vis[idx[blocked]] = 0.0
        return torch.from_numpy(vis)

    def contains(self, point: Tensor) -> bool:
        """Inside when most of six axis rays first meet a back face (robust to open parts such as a ground quad)."""
        p = np.repeat(point.detach().double().numpy().reshape(1, 3), 6, axis=0)
        d = np.concatenate([np.eye(3), -np.eye(3)])
        idx, tri, _ = self.caster.first_faces(p, d)
        back = (self.caster.face_normals[tri] * d[idx]).sum(-1) > 0
        return int(back.sum()) >= 4


def render_asset(asset: Asset | AssetScene, camera: Camera, light: PointLight, edit: MaterialEdit | None = None,
                 shadows: bool = True, ss: int = 1) -> RelitImage:
    """The asset path: embree ray casting, barycentric UVs and normals, bilinear textures, srvol's BRDF."""
    scene = asset if isinstance(asset, AssetScene) else AssetScene.build(asset)
    return render_scene(scene, camera, light, edit, shadows, ss)
