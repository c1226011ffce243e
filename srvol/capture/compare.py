"""An imported capture against its ground truth (a synthetic capture's GT folder): camera alignment
by a similarity fitted on the photos' camera centres, rotation errors, mask IoU."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from srvol.capture.frame import Similarity, fit_similarity, rotation_angle_deg
from srvol.data import read_cameras_json
from srvol.errors import SrvolError
from srvol.types import Camera


@dataclass(frozen=True)
class CameraAlignment:
    """scene_to_gt: the similarity fitted on camera centres (scene frame -> GT frame);
    rotation_deg / center_error: per photo (centre error in GT units); registered: photos matched."""

    scene_to_gt: Similarity
    rotation_deg: dict[str, float]
    center_error: dict[str, float]
    registered: int
    photos: int

    @property
    def median_rotation_deg(self) -> float:
        return float(np.median(list(self.rotation_deg.values())))

    @property
    def registered_share(self) -> float:
        return self.registered / max(self.photos, 1)


def gt_photo_cameras(gt_dir: Path) -> dict[str, Camera]:
    """The photos' GT cameras (gt/photo_cameras.json, keyed by file name) keyed by view name (stem)."""
    path = Path(gt_dir) / "photo_cameras.json"
    if not path.is_file():
        raise SrvolError(f"{path}: no photo cameras (is {gt_dir} the GT folder of a synthetic capture?)")
    return {Path(k).stem: c for k, c in read_cameras_json(path).items()}


def align_cameras(scene_cams: dict[str, Camera], gt_cams: dict[str, Camera]) -> CameraAlignment:
    """Fit scene -> GT on the centres of the photos both have; rotation error of each such photo."""
    names = [n for n in scene_cams if n in gt_cams]
    if len(names) < 3:
        raise SrvolError(f"only {len(names)} photos are both in the scene and in the GT: cannot align")
    src = np.stack([scene_cams[n].center.double().numpy() for n in names])
    dst = np.stack([gt_cams[n].center.double().numpy() for n in names])
    sim = fit_similarity(src, dst)
    rot, cen = {}, {}
    for n in names:
        mapped = sim.camera(scene_cams[n])
        rot[n] = rotation_angle_deg(mapped.W2C[:3, :3].numpy(), gt_cams[n].W2C[:3, :3].double().numpy())
        cen[n] = float(np.linalg.norm(mapped.center.numpy() - gt_cams[n].center.double().numpy()))
    return CameraAlignment(scene_to_gt=sim, rotation_deg=rot, center_error=cen, registered=len(names),
                           photos=len(gt_cams))


def mask_iou(pred: np.ndarray, gt: np.ndarray) -> float:
    """Intersection over union of two (H, W) bool masks (1 when both are empty)."""
    union = np.logical_or(pred, gt).sum()
    return float(np.logical_and(pred, gt).sum() / union) if union else 1.0


def gt_mask_at(gt_dir: Path, name: str, size: tuple[int, int]) -> np.ndarray:
    """(h, w) bool GT mask of photo ``name`` (gt/photo_masks/<name>.png) at working size ``size``:
    cropped to a whole factor and box-averaged > 0.5."""
    from srvol.images import read_png

    m = read_png(Path(gt_dir) / "photo_masks" / f"{name}.png", srgb=False)[..., 0]
    w, h = size
    f = m.shape[1] // w
    return m[:h * f, :w * f].reshape(h, f, w, f).mean(axis=(1, 3)) > 0.5


def mask_ious(scene_dir: Path, gt_dir: Path) -> dict[str, float]:
    """IoU of each imported mask (scene/mask/<stem>.png) with the GT photo mask."""
    from srvol.images import read_png

    out = {}
    for p in sorted((Path(scene_dir) / "mask").glob("*.png")):
        m = read_png(p, srgb=False)[..., 0] > 0.5
        out[p.stem] = mask_iou(m, gt_mask_at(gt_dir, p.stem, (m.shape[1], m.shape[0])))
    return out


def point_distances(points: np.ndarray, mesh, samples: int = 400_000) -> np.ndarray:
    """Each of ``points``' (N, 3) distance to the surface of ``mesh`` (a trimesh), read as the nearest
    of ``samples`` points drawn uniformly over its area: too high by about half their spacing
    (sqrt(area / samples)) at most points, by twice that at a few."""
    import trimesh
    from scipy.spatial import cKDTree

    points = np.asarray(points, np.float64)
    if len(points) == 0:
        return np.zeros(0)
    surface = trimesh.sample.sample_surface(mesh, samples, seed=0)[0]
    return cKDTree(surface).query(points)[0]


def points_to_mesh(points: np.ndarray, mesh, samples: int = 400_000) -> float:
    """Mean distance of ``points`` (N, 3) to the surface of ``mesh`` (a trimesh), in units of the
    mesh's bounding-box diagonal (the object's size). The surface is sampled densely (``samples``
    points; their spacing, ~0.1 % of the size for an object like the bunny, bounds the error)."""
    dist = point_distances(points, mesh, samples)
    return float(np.mean(dist) / np.linalg.norm(mesh.bounds[1] - mesh.bounds[0]))


def object_points(scene_dir: Path) -> np.ndarray:
    """(N, 3) the object's sparse points of an imported scene (capture frame)."""
    import trimesh

    path = Path(scene_dir) / "capture" / "object_points.ply"
    if not path.is_file():
        raise SrvolError(f"{path}: no object points (an import with sparse points writes them)")
    return np.asarray(trimesh.load(path).vertices, np.float64)


def asset_fit_to_points(asset_dir: Path, scene_dir: Path) -> float:
    """How well an asset exported with ``--frame capture`` sits on the capture's sparse object points:
    their mean distance to its mesh (model.obj, else the raw mesh mapped into the capture frame), in
    units of the mesh's bounding-box diagonal."""
    import trimesh

    from srvol.capture.frame import read_normalization

    obj = Path(asset_dir) / "model.obj"
    if obj.is_file():
        mesh = trimesh.load(obj, force="mesh", process=False)
    else:
        raw = np.load(Path(asset_dir) / "raw" / "mesh.npz")
        norm = read_normalization(scene_dir)
        if norm is None:
            raise SrvolError(f"{scene_dir}: not an imported capture")
        mesh = trimesh.Trimesh(norm.inverse().apply(raw["vertices"]), raw["faces"], process=False)
    return points_to_mesh(object_points(scene_dir), mesh)


def gt_mesh_in_capture_frame(scene_dir: Path, gt_dir: Path, scene_to_gt: Similarity):
    """The GT mesh placed in an imported scene's capture frame: GT -> scene (the camera alignment's
    inverse) -> capture (the normalisation's inverse). What a perfect export with --frame capture is."""
    import trimesh

    from srvol.capture.frame import read_normalization

    mesh = trimesh.load(Path(gt_dir) / "mesh.ply", force="mesh", process=False)
    to_capture = scene_to_gt.inverse().then(read_normalization(scene_dir).inverse())
    return trimesh.Trimesh(to_capture.apply(mesh.vertices), mesh.faces, process=False)
