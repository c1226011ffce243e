"""``srvol view SOURCE``: the asset (or run) in the browser, a draggable light, live relit renders.

A viser server (its web client ships inside the viser wheel: no network) shows

* the mesh with its baked albedo (an asset's mesh and albedo map; a run's SDF meshed at 128^3 with
  the albedo field at the vertices), the training cameras as frustums (toggle) and the point light
  as a gizmo;
* the render panel: what :func:`srvol.relight.render.render_scene` -- the relighter, srvol's BRDF,
  shadow rays -- makes of the current viewer camera, light and material. An asset renders through
  embree at full size; a run through the neural path at DRAG_SIZE while anything moves, at full
  size once it has been still for SETTLE_SECONDS;
* the material controls (:class:`~srvol.relight.view_state.MaterialControls`), shadows, intensity;
* "save render" (PNG + EXR + the camera) and "export with edits" (a new asset folder), each printing
  the ``relight`` / ``srvol export`` command that does the same.

One render thread owns the relighter: every TICK_SECONDS it reads the widgets into a
:class:`~srvol.relight.view_state.ViewState` and renders when it differs from the last one.
"""
from __future__ import annotations

import json
import signal
import socket
import threading
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from srvol.errors import SrvolError
from srvol.relight.render import RelitImage, render_scene
from srvol.relight.sources import Source, load_source
from srvol.relight.view_state import (PRESET_NAMES, MaterialControls, ViewerPose, ViewState, camera_from_pose,
                                      export_command, orbit_position, pose_from_camera, relight_command,
                                      render_size)
from srvol.types import Camera

TICK_SECONDS = 0.05
SETTLE_SECONDS = 0.3
EXPORT_FORMATS = ("usd", "glb")
START_CAMERA = (-60.0, 20.0, 4.0)
"""Initial viewer camera: azimuth, elevation (degrees), distance -- the rig's default view (``relight``'s
default camera) from further away, so that the light gizmo is in the picture too."""
DEFAULT_LIGHT = (-100.0, 35.0, 2.0)
"""Initial light: azimuth, elevation (degrees), distance -- 40 degrees to the camera's left and above
it, so that it lights the side the camera sees (and shows left of the object, clear of the panel)."""


@dataclass(frozen=True)
class ViewOptions:
    """host/port of the server; out: folder for saved renders and edited assets; scene: a scene
    folder whose cameras are drawn as frustums (default: the run's scene; an asset has none)."""

    host: str = "127.0.0.1"
    port: int = 8080
    out: Path = Path("view_out")
    scene: Path | None = None


@dataclass(frozen=True)
class DisplayMesh:
    """What the browser draws: vertices (V, 3), faces (F, 3), and either uv (V, 2) + an sRGB albedo
    image (H, W, 3) uint8, or vertex_colors (V, 3) uint8."""

    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray | None = None
    albedo_srgb: np.ndarray | None = None
    vertex_colors: np.ndarray | None = None
    normals: np.ndarray | None = None


@dataclass(frozen=True)
class ShownRender:
    """One image the panel showed: its (W, H) and the relighter's seconds."""

    size: tuple[int, int]
    seconds: float


# ----------------------------------------------------------------------------- what is shown

def to_srgb8(rgb: np.ndarray) -> np.ndarray:
    from srvol.images import linear_to_srgb

    return (linear_to_srgb(rgb) * 255.0 + 0.5).astype(np.uint8)


def describe(edit) -> str:
    return "as baked" if edit.is_identity else edit.describe()


def display_mesh(source: Source, source_path: Path) -> DisplayMesh:
    """An asset's own mesh and albedo map; a run's SDF meshed at 128^3, albedo field at the vertices."""
    if source.kind == "asset":
        from srvol.export.asset import load_asset

        asset = load_asset(source_path)
        return DisplayMesh(asset.mesh.vertices, asset.mesh.faces, uv=asset.mesh.uv,
                           albedo_srgb=to_srgb8(asset.textures.albedo[..., :3]), normals=asset.mesh.normals)
    import torch

    from srvol.export.extract import ExtractOptions, extract_mesh

    mesh = extract_mesh(source.scene.sdf_fn, ExtractOptions(resolution=128, normals=True)).mesh
    with torch.no_grad():
        albedo = source.scene.material_fn(torch.from_numpy(np.ascontiguousarray(mesh.vertices))).albedo
    return DisplayMesh(mesh.vertices, mesh.faces, vertex_colors=to_srgb8(albedo.float().numpy()),
                       normals=mesh.normals)


def training_cameras(source: Source, scene_dir: Path | None) -> dict[str, Camera]:
    root = scene_dir or source.scene_dir
    if root is None or not Path(root).is_dir():
        return {}
    from srvol.data import load_scene

    scene = load_scene(root, load_images=False)
    return {name: scene.views[name].camera for name in scene.train}


def check_port_free(host: str, port: int) -> None:
    """One line and exit 2 for a port that is taken (viser would silently move to the next one)."""
    if not 1 <= port <= 65535:
        raise SrvolError(f"--port {port}: must be 1..65535")
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        # as the server binds (asyncio): a port left in TIME_WAIT by a closed connection is free,
        # one that a process listens on is not
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError as e:
            raise SrvolError(f"--port {port}: cannot listen on {host}:{port} ({e.strerror or e}); "
                             "choose another port") from None


# ----------------------------------------------------------------------------- the server

class Viewer:
    """A running ``srvol view``: the viser server, its scene and widgets, the render thread.

    ``state()`` reads the widgets; ``panel`` holds the last rendered image (``last_image``, ``last_state``;
    ``recent``: the sizes and seconds of the last renders); ``stop()`` ends it all.
    """

    def __init__(self, source_path: Path, options: ViewOptions = ViewOptions()):
        self.source_path = Path(source_path)
        self.options = options
        self.source = load_source(self.source_path, None)
        check_port_free(options.host, options.port)
        mesh = display_mesh(self.source, self.source_path)
        cameras = training_cameras(self.source, options.scene)
        import viser

        self.server = viser.ViserServer(host=options.host, port=options.port, verbose=False)
        if self.server.get_port() != options.port:  # taken between our check and viser's bind
            self.server.stop()
            raise SrvolError(f"--port {options.port}: in use; choose another port")
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.last_image: RelitImage | None = None
        self.last_state: ViewState | None = None
        self.renders = 0
        self.recent: deque[ShownRender] = deque(maxlen=64)
        self._build_scene(mesh, cameras)
        self._build_gui()
        self._thread = threading.Thread(target=self._render_loop, name="srvol-view-render", daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        host = "localhost" if self.options.host in ("0.0.0.0", "127.0.0.1") else self.options.host
        return f"http://{host}:{self.server.get_port()}"

    # -- scene
    def _build_scene(self, mesh: DisplayMesh, cameras: dict[str, Camera]) -> None:
        import torch
        import trimesh
        from PIL import Image

        from srvol.camera_rig import rig_camera

        scene = self.server.scene
        scene.set_up_direction("+z")
        tm = trimesh.Trimesh(mesh.vertices, mesh.faces, vertex_normals=mesh.normals, process=False)
        if mesh.albedo_srgb is not None and mesh.uv is not None:
            material = trimesh.visual.material.PBRMaterial(baseColorTexture=Image.fromarray(mesh.albedo_srgb),
                                                           metallicFactor=0.0, roughnessFactor=1.0)
            tm.visual = trimesh.visual.TextureVisuals(uv=mesh.uv, material=material)
        elif mesh.vertex_colors is not None:
            tm.visual.vertex_colors = np.concatenate(
                [mesh.vertex_colors, np.full((len(mesh.vertex_colors), 1), 255, np.uint8)], 1)
        scene.add_mesh_trimesh("/object", tm)
        self._frustums = []
        for name, cam in cameras.items():
            pose = pose_from_camera(cam)
            self._frustums.append(scene.add_camera_frustum(
                f"/training_cameras/{name}", fov=pose.fov_y, aspect=pose.aspect, scale=0.12,
                wxyz=pose.wxyz, position=pose.position, color=(60, 90, 200), thickness=0.004))
        az, el, distance = START_CAMERA
        start = rig_camera(torch.from_numpy(orbit_position(az, el, 1.0)), 640, 480, distance=distance)
        pose = pose_from_camera(start)
        self.default_pose = pose
        self.server.initial_camera.position = pose.position
        self.server.initial_camera.look_at = (0.0, 0.0, 0.0)
        self.server.initial_camera.up = (0.0, 0.0, 1.0)
        self.server.initial_camera.fov = pose.fov_y
        light = orbit_position(*DEFAULT_LIGHT)
        self.light_handle = scene.add_transform_controls("/light", scale=0.35, disable_rotations=True,
                                                         position=tuple(float(c) for c in light))
        scene.add_icosphere("/light/bulb", radius=0.04, color=(255, 220, 80))

    # -- widgets
    def _build_gui(self) -> None:
        gui = self.server.gui
        blank = np.zeros((480, 640, 3), np.uint8)
        self.panel = gui.add_image(blank, label="relit (srvol's relighter)", format="png")
        self.status = gui.add_markdown("rendering ...")
        with gui.add_folder("Light"):
            self.intensity = gui.add_slider("intensity", min=0.0, max=100.0, step=0.5,
                                            initial_value=float(np.mean(self.source.intensity)))
            self.shadows = gui.add_checkbox("shadows", initial_value=True)
        with gui.add_folder("Material"):
            self.preset = gui.add_dropdown("preset", PRESET_NAMES, initial_value=PRESET_NAMES[0])
            self.roughness = gui.add_slider("roughness scale", min=0.0, max=2.0, step=0.05, initial_value=1.0)
            self.specular = gui.add_slider("specular scale", min=0.0, max=4.0, step=0.05, initial_value=1.0)
            self.tint = gui.add_rgb("albedo tint", initial_value=(255, 255, 255))
        with gui.add_folder("Scene"):
            self.show_cameras = gui.add_checkbox("training cameras", initial_value=bool(self._frustums),
                                                 disabled=not self._frustums)
            self.show_cameras.on_update(lambda _: self._toggle_cameras())
        self.save_button = gui.add_button("save render")
        self.save_button.on_click(lambda _: self._report(self.save_render))
        self.export_button = gui.add_button("export with edits")
        self.export_button.on_click(lambda _: self._report(self.export_with_edits))
        self.commands = gui.add_markdown("")

    def _toggle_cameras(self) -> None:
        for f in self._frustums:
            f.visible = bool(self.show_cameras.value)

    def _report(self, action) -> None:
        self.commands.content = "working ..."
        try:
            command = action()
        except SrvolError as e:
            command = f"srvol: error: {e}"
        print(command, flush=True)
        self.commands.content = f"```\n{command}\n```"

    # -- state
    def viewer_pose(self) -> ViewerPose:
        """The first connected browser's camera, else the initial one."""
        for client in self.server.get_clients().values():
            cam = client.camera
            try:
                return ViewerPose(position=tuple(float(c) for c in cam.position),
                                  wxyz=tuple(float(c) for c in cam.wxyz), fov_y=float(cam.fov),
                                  aspect=float(cam.aspect))
            except (AssertionError, ZeroDivisionError):  # the client has not reported its camera yet
                continue
        return self.default_pose

    def material_controls(self) -> MaterialControls:
        return MaterialControls(preset=self.preset.value, roughness_scale=float(self.roughness.value),
                                specular_scale=float(self.specular.value),
                                albedo_tint=tuple(float(c) / 255.0 for c in self.tint.value))

    def state(self) -> ViewState:
        return ViewState(pose=self.viewer_pose(), light_position=tuple(float(c) for c in self.light_handle.position),
                         intensity=float(self.intensity.value), shadows=bool(self.shadows.value),
                         material=self.material_controls())

    # -- rendering
    def render(self, state: ViewState, size: tuple[int, int]) -> RelitImage:
        camera = camera_from_pose(state.pose, *size)
        return render_scene(self.source.scene, camera, state.light(), state.material.edit(), state.shadows)

    def _render_loop(self) -> None:
        shown: tuple[ViewState, tuple[int, int]] | None = None
        last, changed_at = None, time.monotonic()
        while not self._stop.wait(TICK_SECONDS):
            state = self.state()
            now = time.monotonic()
            if state != last:
                last, changed_at = state, now
            settled = now - changed_at >= SETTLE_SECONDS
            size = render_size(self.source.kind, settled, state.pose.aspect)
            if shown == (state, size) or (shown is not None and shown[0] == state and not settled):
                continue
            t0 = time.perf_counter()
            try:
                image = self.render(state, size)
            except SrvolError as e:
                self.status.content = f"render failed: {e}"
                shown = (state, size)
                continue
            seconds = time.perf_counter() - t0
            self.panel.image = to_srgb8(image.rgb)
            self.status.content = (f"{size[0]}x{size[1]}, {seconds:.2f} s, "
                                   f"{'embree' if self.source.kind == 'asset' else 'neural'} path, "
                                   f"material: {describe(state.material.edit())}")
            with self._lock:  # after the panel: a waiter sees the image it is told about
                self.last_image, self.last_state, self.renders = image, state, self.renders + 1
                self.recent.append(ShownRender(size, seconds))
            shown = (state, size)

    def wait_for_render(self, after: int = 0, timeout: float = 60.0) -> RelitImage:
        """Block until more than ``after`` renders have been shown; the last image."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            with self._lock:
                if self.renders > after and self.last_image is not None:
                    return self.last_image
            time.sleep(TICK_SECONDS)
        raise TimeoutError(f"no render within {timeout} s")

    # -- buttons
    def _next_path(self, stem: str, suffix: str = "") -> Path:
        self.options.out.mkdir(parents=True, exist_ok=True)
        k = 0
        while any(self.options.out.glob(f"{stem}_{k:03d}*")):
            k += 1
        return self.options.out / f"{stem}_{k:03d}{suffix}"

    def save_render(self) -> str:
        """Render the current state at full size into OUT/render_NNN.{png,exr} (+ _camera.json); the
        equivalent ``relight`` command."""
        from srvol.atomic import atomic_write_text
        from srvol.data import camera_to_json
        from srvol.images import write_exr, write_png

        state = self.state()
        size = render_size("asset", True, state.pose.aspect)
        image = self.render(state, size)
        base = self._next_path("render")
        cam_file = base.with_name(base.name + "_camera.json")
        camera = camera_from_pose(state.pose, *size)
        atomic_write_text(cam_file, json.dumps({base.name + ".exr": camera_to_json(camera)}))
        write_exr(base.with_suffix(".exr"), image.rgb)
        write_png(base.with_suffix(".png"), image.rgb, srgb=True)
        return (f"saved {base}.png and {base}.exr; the same with relight:\n"
                + relight_command(self.source_path, cam_file, size, state, base.with_suffix(".exr")))

    def export_with_edits(self) -> str:
        """A new asset folder OUT/asset_edited_NNN with the edited maps (atomically, through the exporter's
        writers); the equivalent ``srvol export`` command."""
        from functools import partial

        from srvol.relight.edits import edit_textures

        edit = self.material_controls().edit()
        out = self._next_path("asset_edited")
        texture_edit = None if edit.is_identity else partial(edit_textures, edit=edit)
        if self.source.kind == "asset":
            from srvol.export.pipeline import reexport_asset

            reexport_asset(self.source_path, out, EXPORT_FORMATS, texture_edit)
        else:
            from srvol.checkpoint import load_model  # a run: the whole export, as `srvol export` does it
            from srvol.export.pipeline import ExportOptions, export_fields

            model, info = load_model(self.source_path, device="cpu")
            export_fields(model.sdf, model.material, out,
                          ExportOptions(formats=EXPORT_FORMATS, hr_pixel_size=info.hr_pixel_size,
                                        sdf_cell=model.finest_sdf_cell()), texture_edit)
        return (f"wrote {out} (material: {describe(edit)}); the same with srvol export:\n"
                + export_command(self.source_path, edit, EXPORT_FORMATS, out))

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=30)
        self.server.stop()


# ----------------------------------------------------------------------------- command line

def add_parser(sub) -> None:
    p = sub.add_parser(
        "view", help="look at a run or an asset in the browser: drag the light, edit the material, live",
        description="Start a viser server (the browser client ships with viser; no network needed) showing the "
                    "mesh with its baked albedo, the training cameras and a point light you drag; a panel shows "
                    "srvol's relighter's render of the current view (an asset: embree, 640x480; a run: the "
                    "neural path, reduced while dragging). Material controls, 'save render' and 'export with "
                    "edits' (each prints the equivalent relight / srvol export command).")
    p.add_argument("source", type=Path, metavar="SOURCE", help="a training run folder or an exported asset folder")
    p.add_argument("--port", type=int, default=8080, help="port to serve on (default 8080)")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to listen on (default 127.0.0.1, this machine only; 0.0.0.0 for all)")
    p.add_argument("--scene", type=Path, metavar="DIR",
                   help="scene folder whose training cameras to draw (default: the run's scene)")
    p.add_argument("--out", type=Path, default=Path("view_out"),
                   help="folder for saved renders and edited assets (default ./view_out)")
    p.set_defaults(func=run_view)


def run_view(args) -> int:
    # The line below promises that Ctrl-C stops the server. A process started with SIGINT ignored
    # (a job a non-interactive shell put in the background, and whatever it starts) would never see
    # it: Python installs its KeyboardInterrupt handler only where SIGINT is not ignored.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    viewer = Viewer(args.source, ViewOptions(host=args.host, port=args.port, out=args.out, scene=args.scene))
    try:
        print(f"srvol view: {viewer.source.label} at {viewer.url}  (Ctrl-C stops)", flush=True)
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        pass
    finally:
        viewer.stop()
    print("srvol view: stopped", flush=True)
    return 0
