"""`srvol view`: the server in headless Chromium, a light moved through viser's API, a clean stop, bad input."""
from __future__ import annotations

import base64
import io
import json
import shutil
import socket
import subprocess
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from websockets.sync.client import connect

from srvol.cli import main as srvol_main
from srvol.images import write_png
from srvol.relight.view import ViewOptions, Viewer, check_port_free

from view_fixtures import export_sphere, free_port

CHROMIUM = next((p for p in (shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome")) if p), None)


@pytest.fixture(scope="module")
def asset(tmp_path_factory):
    return export_sphere(tmp_path_factory.mktemp("view") / "asset")


CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync",
                  "--hide-scrollbars", "--window-size=1000,700")


class HeadlessPage:
    """A page open in headless Chromium, screenshotted on demand over the DevTools protocol (a live
    page: viser's client keeps its websocket open, so a one-shot --screenshot has no moment to wait for)."""

    def __init__(self, url: str, profile: Path):
        self.proc = subprocess.Popen(["nice", "-n", "19", CHROMIUM, *CHROMIUM_FLAGS, f"--user-data-dir={profile}",
                                      "--remote-debugging-port=0", url],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        port_file, end = profile / "DevToolsActivePort", time.monotonic() + 60
        while not port_file.is_file() or not port_file.read_text().strip():
            if time.monotonic() > end or self.proc.poll() is not None:
                raise RuntimeError("chromium did not start its DevTools endpoint")
            time.sleep(0.2)
        port = int(port_file.read_text().split()[0])
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=10) as r:
            page = next(t for t in json.loads(r.read()) if t["type"] == "page")
        self.ws = connect(page["webSocketDebuggerUrl"], max_size=None, open_timeout=10)
        self.calls = 0

    def screenshot(self) -> np.ndarray:
        self.calls += 1
        self.ws.send(json.dumps({"id": self.calls, "method": "Page.captureScreenshot", "params": {"format": "png"}}))
        while True:
            reply = json.loads(self.ws.recv(timeout=60))
            if reply.get("id") == self.calls:
                break
        png = base64.b64decode(reply["result"]["data"])
        return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), np.float32) / 255.0

    def close(self) -> None:
        self.ws.close()
        self.proc.terminate()
        self.proc.wait(timeout=30)


def canvas_centre(shot: np.ndarray) -> np.ndarray:
    h, w = shot.shape[:2]
    return shot[h // 2 - 30:h // 2 + 30, w // 2 - 30:w // 2 + 30]


def centre_shows_mesh(shot: np.ndarray) -> bool:
    background = shot[shot.shape[0] // 2, 60]  # left edge, mid-height: empty canvas
    return (np.abs(canvas_centre(shot) - background).max(-1) > 0.1).mean() > 0.9


def until_rendered(viewer: Viewer, wanted, renders: int = 10):
    """The panel's image once the state it shows satisfies ``wanted`` (at most ``renders`` more renders)."""
    for _ in range(renders):
        n = viewer.renders
        if viewer.last_state is not None and wanted(viewer.last_state):
            return viewer.last_image
        viewer.wait_for_render(n)
    raise AssertionError("the render panel never showed the wanted state")


@pytest.mark.skipif(CHROMIUM is None, reason="SKIPPED LOUDLY: no chromium on this machine "
                                             "(.ci/run installs Debian's chromium; install it to run this test)")
def test_view_in_chromium_then_a_light_move_rerenders_then_a_clean_stop(asset, tmp_path):
    port = free_port()
    viewer = Viewer(asset, ViewOptions(port=port, out=tmp_path / "out"))
    try:
        first = viewer.wait_for_render()
        assert first.mask.mean() > 0.05  # the panel's first render sees the sphere
        page = HeadlessPage(viewer.url, tmp_path / "profile")
        try:  # the client connects, loads the mesh and draws: up to 60 s on a busy machine
            end = time.monotonic() + 60
            while not centre_shows_mesh(shot := page.screenshot()) and time.monotonic() < end:
                time.sleep(1.0)
        finally:
            page.close()
            write_png(tmp_path / "shot.png", shot, srgb=False)
        assert shot.shape[1] == 1000 and shot.shape[0] > 400
        background = shot[shot.shape[0] // 2, 60]  # left edge, mid-height: empty canvas
        drawn = np.abs(shot - background).max(-1) > 0.1
        assert drawn.mean() > 0.05, "blank page"
        # The mesh sits at the canvas centre (the camera looks at the origin), in its albedo's colours:
        # a pink-violet ramp (red and blue above green), not the grey of an untextured mesh.
        centre = canvas_centre(shot)
        assert centre_shows_mesh(shot)
        assert (centre[..., 0] - centre[..., 1]).mean() > 0.08 and (centre[..., 2] - centre[..., 1]).mean() > 0.05
        # the render panel (GUI, top right) holds the relit image: dark background, lit sphere
        panel = shot[100:240, 680:970]
        assert (panel.max(-1) < 0.05).mean() > 0.2 and (panel.max(-1) > 0.3).mean() > 0.02

        # move the light through viser's Python API: from the camera's side to behind the sphere
        # (the browser has gone: wait for the panel to show the initial camera again, then move the light)
        until_rendered(viewer, lambda state: state.pose == viewer.default_pose)
        before = viewer.panel.image.copy()
        viewer.light_handle.position = (-1.5, 2.2, 0.3)
        after = until_rendered(viewer, lambda state: state.light_position == pytest.approx((-1.5, 2.2, 0.3)))
        assert viewer.last_state.pose == viewer.default_pose
        assert np.abs(viewer.panel.image.astype(float) - before.astype(float)).mean() > 5.0
        assert after.rgb.mean() < 0.5 * first.rgb.mean()  # lit from behind: mostly dark
    finally:
        viewer.stop()
    assert not viewer._thread.is_alive()
    with pytest.raises(ConnectionRefusedError):  # nobody listens any more
        socket.create_connection(("127.0.0.1", port), timeout=5).close()
    check_port_free("127.0.0.1", port)  # and `srvol view --port` may have it again


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_a_folder_neither_run_nor_asset_is_one_line_and_exit_2(tmp_path, capsys):
    (tmp_path / "photos").mkdir()
    assert srvol_main(["view", str(tmp_path / "photos"), "--port", str(free_port())]) == 2
    line = _one_error_line(capsys)
    assert line.startswith("srvol: error:") and "neither a training run" in line
    assert srvol_main(["view", str(tmp_path / "missing")]) == 2
    assert "no such folder" in _one_error_line(capsys)


def test_a_port_in_use_is_one_line_and_exit_2(asset, capsys):
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen(1)
        port = busy.getsockname()[1]
        t0 = time.monotonic()
        assert srvol_main(["view", str(asset), "--port", str(port)]) == 2
        assert time.monotonic() - t0 < 30  # refused, not served on another port
    line = _one_error_line(capsys)
    assert line.startswith(f"srvol: error: --port {port}: cannot listen")


def test_the_command_serves_the_page_and_stops_on_ctrl_c(asset, tmp_path):
    """`srvol view ASSET --port P` as a user runs it: one line with the URL, the page is served
    (viser's bundled client, no network), Ctrl-C (SIGINT) stops it with exit status 0 -- even when
    it was started with SIGINT ignored."""
    import signal
    import sys

    port = free_port()
    # started with SIGINT ignored, as a non-interactive shell starts a background job: Ctrl-C
    # (SIGINT) must stop it all the same (the command installs its handler itself)
    proc = subprocess.Popen([sys.executable, "-m", "srvol", "view", str(asset), "--port", str(port),
                             "--out", str(tmp_path / "out")], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    try:
        line = ""
        end = time.monotonic() + 120
        while "srvol view:" not in line and time.monotonic() < end and proc.poll() is None:
            line = proc.stdout.readline()
        assert line.strip() == f"srvol view: asset:asset at http://localhost:{port}  (Ctrl-C stops)"
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=30) as r:
            assert r.status == 200 and b"<html" in r.read().lower()
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err[-500:]
    assert "srvol view: stopped" in out
