"""Headless-browser check of ``dexmots-view``: the page really draws the hand and the object.

    python scripts/browser_check.py                        # records 2 worlds x 10 steps, checks, prints JSON
    python scripts/browser_check.py --recording run.mcap --out docs/viewer.png

Starts a :class:`~dexmots_rl.viz.viewer.ReplayViewer` on a free port, opens it in headless Chromium
(fresh profile, software WebGL) and takes screenshots over the DevTools protocol (a websocket; Chromium's
``--screenshot`` flag alone captures the page before the scene arrives) until the scene is drawn or
``--timeout`` passes. The check projects each world's hand links and object through the viewer's
initial camera and counts pixels of the hand colour (orange-brown) and the object colour (blue)
in a box around them: both counts must reach ``--min-pixels``. Exit status 0 when the check passes,
1 when it fails, 2 when no Chromium is found.

Example (needs Chromium; from the repository root):
    .venv/bin/python scripts/browser_check.py --out /tmp/viewer.png --size 800 500
    {"region": [...], "hand_pixels": 4846, "object_pixels": 6382, ..., "ok": true, ...}
"""

from __future__ import annotations

import argparse
import base64
import io
import json
import logging
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import numpy as np

log = logging.getLogger("browser_check")

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable", "chrome")
CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync", "--no-first-run",
                  "--disable-dev-shm-usage", "--remote-allow-origins=*", "--hide-scrollbars", "--mute-audio")
WIDTH, HEIGHT = 1280, 800
# viser warns about software WebGL in a toast over the canvas; hide toasts in the screenshot
HIDE_TOASTS = ("document.head.insertAdjacentHTML('beforeend', "
               "'<style>.mantine-Notifications-root, [class*=Notification]{display:none !important}</style>')")


def find_chromium() -> str | None:
    """``$CHROMIUM`` or the first Chromium/Chrome executable on PATH."""
    env = os.environ.get("CHROMIUM")
    if env and shutil.which(env):
        return shutil.which(env)
    return next((shutil.which(n) for n in CHROMIUM_NAMES if shutil.which(n)), None)


class CDP:
    """A minimal Chrome DevTools Protocol client over one page's websocket (``websocket-client``)."""

    def __init__(self, ws_url: str, timeout: float = 30.0):
        import websocket

        self.ws = websocket.create_connection(ws_url, timeout=timeout, suppress_origin=True)
        self._id = 0

    def call(self, method: str, **params):
        self._id += 1
        self.ws.send(json.dumps({"id": self._id, "method": method, "params": params}))
        while True:  # skip events until our answer arrives
            msg = json.loads(self.ws.recv())
            if msg.get("id") == self._id:
                if "error" in msg:
                    raise RuntimeError(f"CDP {method}: {msg['error']}")
                return msg.get("result", {})

    def close(self):
        self.ws.close()


def launch_chromium(binary: str, profile: Path, timeout: float = 30.0,
                    size=(WIDTH, HEIGHT)) -> tuple[subprocess.Popen, str]:
    """Start headless Chromium on about:blank; returns the process and the page's websocket URL."""
    proc = subprocess.Popen([binary, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", "--remote-debugging-port=0",
                             f"--window-size={size[0]},{size[1]}", "about:blank"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    port_file, deadline = profile / "DevToolsActivePort", time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"{binary} exited with status {proc.returncode} before DevTools came up")
        if port_file.is_file() and port_file.read_text().strip():
            port = int(port_file.read_text().split()[0])
            try:
                targets = json.loads(urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=5).read())
            except OSError:
                time.sleep(0.2)
                continue
            pages = [t for t in targets if t.get("type") == "page"]
            if pages:
                return proc, pages[0]["webSocketDebuggerUrl"]
        time.sleep(0.2)
    proc.kill()
    raise RuntimeError(f"{binary} did not open DevTools within {timeout:.0f} s")


def _project(points: np.ndarray, eye: np.ndarray, target: np.ndarray, fov: float, w: int, h: int) -> np.ndarray:
    """Pixel coordinates of world ``points`` [K, 3] for a z-up perspective camera (vertical ``fov``)."""
    fwd = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    rel = points - eye
    depth = rel @ fwd
    t = math.tan(fov / 2)
    x = (rel @ right) / depth / (t * w / h)
    y = (rel @ up) / depth / t
    return np.stack([(x + 1) * w / 2, (1 - y) * h / 2], -1)


def colour_masks(img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Boolean masks of hand-coloured (orange-brown) and object-coloured (blue) pixels of an RGB image."""
    rgb = img[..., :3].astype(np.float64) / 255.0
    mx, mn = rgb.max(-1), rgb.min(-1)
    sat = (mx - mn) / np.maximum(mx, 1e-6)
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    lit = mx > 0.15
    hand = lit & (sat > 0.2) & (r > g) & (g > b)
    obj = lit & (sat > 0.2) & (b > r) & (b > g) & (b - r > 0.1)
    return hand, obj


def check_image(img: np.ndarray, viewer, min_pixels: int) -> dict:
    """Count hand and object pixels in the box where the camera sees the bodies."""
    rec, h, w = viewer.rec, img.shape[0], img.shape[1]
    cam = viewer.server.initial_camera
    worlds = viewer._worlds()
    off = rec.world_offsets.double().numpy()[worlds] if len(worlds) > 1 else rec.world_offsets.double().numpy().mean(
        0, keepdims=True)
    pos = rec.frames["body_pose"][viewer.frame][worlds, :, :3].double().numpy() + off[:, None]
    px = _project(pos.reshape(-1, 3), np.asarray(cam.position), np.asarray(cam.look_at), cam.fov, w, h)
    pad = 0.15 * max(w, h)
    x0, y0 = (px.min(0) - pad).clip(0).astype(int)
    x1, y1 = np.minimum(px.max(0) + pad, [w, h]).astype(int)
    hand, obj = colour_masks(img)
    region = np.zeros_like(hand)
    region[y0:y1, x0:x1] = True
    result = {"region": [int(x0), int(y0), int(x1), int(y1)], "hand_pixels": int((hand & region).sum()),
              "object_pixels": int((obj & region).sum()), "hand_pixels_outside": int((hand & ~region).sum()),
              "object_pixels_outside": int((obj & ~region).sum())}
    result["ok"] = result["hand_pixels"] >= min_pixels and result["object_pixels"] >= min_pixels
    return result


# the viewer's timeline is viser's "Frame" slider: a visible [role=slider] element and its label
TIMELINE_JS = """(() => {
  const visible = e => { const r = e.getBoundingClientRect(); return r.width > 0 && r.height > 0; };
  const sliders = [...document.querySelectorAll('[role="slider"]')].filter(visible).length;
  return {sliders: sliders, frame_label: document.body.innerText.includes("Frame")};
})()"""


def timeline_drawn(cdp) -> dict:
    """``{"sliders": n, "frame_label": bool}`` of the page (DevTools ``Runtime.evaluate``)."""
    reply = cdp.call("Runtime.evaluate", expression=TIMELINE_JS, returnByValue=True)
    return reply.get("result", {}).get("value") or {"sliders": 0, "frame_label": False}


def make_recording(path: Path, num_envs: int = 2, steps: int = 10) -> Path:
    """A small scripted screw_claw recording (the fingers close on the knob)."""
    from dexmots_rl.envs import ScriptedPolicy, make_env
    from dexmots_rl.viz import EpisodeRecorder

    env = make_env("screw_claw", num_envs=num_envs, differentiable=False, seed=0, max_episode_steps=steps,
                   action="torque")
    with EpisodeRecorder(path, env) as rec:
        rec.record_rollout(env.rollout(steps, ScriptedPolicy(env.base_env), auto_reset=False,
                                       break_when_any_done=False, tensordict=env.reset()))
    return path


def run_check(recording: str | Path, out: str | Path | None = None, chromium: str | None = None,
              timeout: float = 90.0, min_pixels: int = 200, size: tuple[int, int] = (WIDTH, HEIGHT),
              shadows: bool = False) -> dict:
    """Serve ``recording``, screenshot it in headless Chromium until the check passes (or ``timeout``)."""
    from PIL import Image

    from dexmots_rl.viz.viewer import ReplayViewer

    binary = chromium or find_chromium()
    if binary is None:
        raise FileNotFoundError("no Chromium found (install it, e.g. apt-get install chromium, or set $CHROMIUM)")
    viewer = ReplayViewer(recording, port=0, shadows=shadows)
    viewer.set_frame(viewer.rec.num_frames - 1)
    profile = Path(tempfile.mkdtemp(prefix="dexmots-chromium-"))
    proc = None
    try:
        start = time.monotonic()
        proc, ws_url = launch_chromium(binary, profile, size=size)
        cdp = CDP(ws_url)
        cdp.call("Page.enable")
        cdp.call("Emulation.setDeviceMetricsOverride", width=size[0], height=size[1], deviceScaleFactor=1,
                 mobile=False)
        cdp.call("Page.navigate", url=viewer.url)
        log.info("chromium up and navigating after %.1f s", time.monotonic() - start)
        result, png = {"ok": False}, b""
        while time.monotonic() - start < timeout:
            time.sleep(1.0)
            cdp.call("Runtime.evaluate", expression=HIDE_TOASTS)
            png = base64.b64decode(cdp.call("Page.captureScreenshot", format="png")["data"])
            img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))
            result = check_image(img, viewer, min_pixels)
            timeline = timeline_drawn(cdp)
            result["timeline"] = bool(timeline["sliders"] >= 1 and timeline["frame_label"])
            result["ok"] = result["ok"] and result["timeline"]
            log.info("%.1f s: %d hand and %d object pixels, timeline %s", time.monotonic() - start,
                     result["hand_pixels"], result["object_pixels"], result["timeline"])
            if result["ok"]:
                break
        result["seconds"] = round(time.monotonic() - start, 1)
        result["url"] = viewer.url
        if out is not None and png:
            Path(out).parent.mkdir(parents=True, exist_ok=True)
            Path(out).write_bytes(png)
            result["screenshot"] = str(out)
        cdp.close()
        return result
    finally:
        if proc is not None:
            proc.kill()
            proc.wait(timeout=10)
        viewer.stop()
        shutil.rmtree(profile, ignore_errors=True)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--recording", help="an MCAP recording (default: record 2 worlds x 10 steps)")
    p.add_argument("--out", default=None, help="save the last screenshot (PNG) here")
    p.add_argument("--chromium", default=None, help="browser executable (default: $CHROMIUM or PATH)")
    p.add_argument("--timeout", type=float, default=90.0)
    p.add_argument("--min-pixels", type=int, default=200)
    p.add_argument("--size", type=int, nargs=2, default=(WIDTH, HEIGHT), metavar=("W", "H"))
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="%(asctime)s %(message)s")
    if (args.chromium or find_chromium()) is None:
        print(json.dumps({"ok": False, "error": "no chromium found"}))
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        recording = args.recording or make_recording(Path(tmp) / "check.mcap")
        result = run_check(recording, args.out, args.chromium, args.timeout, args.min_pixels, tuple(args.size))
    print(json.dumps(result))
    return 0 if result["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
