"""Headless-browser check of ``dexmots-view``: the page really draws every part of the scene.

    python scripts/browser_check.py                        # records 2 worlds x 10 steps, checks, prints JSON
    python scripts/browser_check.py --recording run.mcap --out docs/viewer.png

Starts a :class:`~dexmots_rl.viz.viewer.ReplayViewer` on a free port, opens it in headless Chromium
(fresh profile, software WebGL) and takes screenshots over the DevTools protocol (a websocket; Chromium's
``--screenshot`` flag alone captures the page before the scene arrives) until the scene is drawn or
``--timeout`` passes. Then, for each group of the scene's meshes (the hand's links, the palm, the table,
each of the object's bodies by name: :func:`scene_groups`), it hides the group in the viewer, takes another
screenshot and counts the pixels that changed: what a group's meshes cover on screen. Every group must
change at least ``--min-pixels``; the timeline slider must be drawn. Exit status 0 when the check passes,
1 when it fails, 2 when no Chromium is found.

Example (needs Chromium; from the repository root):
    .venv/bin/python scripts/browser_check.py --out /tmp/viewer.png --size 800 500
    {"pixels": {"hand": 4846, "object": 6382}, "timeline": true, "ok": true, ...}
"""

from __future__ import annotations

import argparse
import base64
import io
import json
import logging
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
# the control panel is the page's first mantine Paper (figures for the docs show the scene alone)
HIDE_PANEL = "document.querySelector('.mantine-Paper-root').style.display = 'none'"


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


def scene_groups(viewer) -> dict[str, list[str]]:
    """The viewer's mesh handles by what they draw: ``hand`` (the links), ``palm``, ``table``, ``base`` (an
    object's static parts) and ``object:<body>`` for each of the object's bodies."""
    groups: dict[str, list[str]] = {}
    for k, part in enumerate(viewer.rec.geometry.parts):
        name = f"object:{part.name}" if part.role == "object" else part.role
        groups.setdefault(name, []).append(f"part{k}")
    return groups


def _screenshot(cdp) -> np.ndarray:
    from PIL import Image

    png = base64.b64decode(cdp.call("Page.captureScreenshot", format="png")["data"])
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")), png


def _changed(a: np.ndarray, b: np.ndarray) -> int:
    return int((np.abs(a.astype(np.int16) - b.astype(np.int16)).max(-1) > 12).sum())


def _settled(cdp, settle: float, timeout: float, min_changed: int = 0, reference=None):
    """Screenshots until two in a row agree (and, given a ``reference``, one differs from it by
    ``min_changed`` pixels or ``timeout`` passes); returns the last image and PNG."""
    deadline = time.monotonic() + timeout
    img, png = _screenshot(cdp)
    while time.monotonic() < deadline:
        time.sleep(settle)
        nxt, png = _screenshot(cdp)
        stable = _changed(nxt, img) == 0
        img = nxt
        if stable and (reference is None or _changed(img, reference) >= min_changed):
            break
    return img, png


def group_pixels(viewer, cdp, base: np.ndarray, min_pixels: int, settle: float = 0.5,
                 timeout: float = 8.0) -> dict[str, int]:
    """For each of :func:`scene_groups`: the pixels that change when the group is hidden."""
    out = {}
    for name, handles in scene_groups(viewer).items():
        for h in handles:
            viewer._handles[h].visible = False
        img, _ = _settled(cdp, settle, timeout, min_pixels, reference=base)
        out[name] = _changed(img, base)
        for h in handles:
            viewer._handles[h].visible = True
        _settled(cdp, settle, timeout, 1, reference=img)
    return out


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
              shadows: bool = False, groups: bool = True, viewer_kwargs: dict | None = None,
              hide_panel: bool = False) -> dict:
    """Serve ``recording`` and screenshot it in headless Chromium once the scene has arrived (or ``timeout``);
    with ``groups``, count each group's pixels (see the module docstring). ``out``: the full screenshot, without
    the control panel when ``hide_panel``."""
    from dexmots_rl.viz.viewer import ReplayViewer

    binary = chromium or find_chromium()
    if binary is None:
        raise FileNotFoundError("no Chromium found (install it, e.g. apt-get install chromium, or set $CHROMIUM)")
    viewer = ReplayViewer(recording, port=0, shadows=shadows, **(viewer_kwargs or {}))
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
        result, png, img = {"ok": False}, b"", None
        while time.monotonic() - start < timeout:  # the scene has arrived when the timeline is drawn and
            time.sleep(1.0)                         # two screenshots in a row agree
            cdp.call("Runtime.evaluate", expression=HIDE_TOASTS)
            timeline = timeline_drawn(cdp)
            result["timeline"] = bool(timeline["sliders"] >= 1 and timeline["frame_label"])
            if result["timeline"]:
                if hide_panel:
                    cdp.call("Runtime.evaluate", expression=HIDE_PANEL)
                img, png = _settled(cdp, 1.0, max(1.0, timeout - (time.monotonic() - start)))
                break
        if img is not None and groups:
            result["pixels"] = group_pixels(viewer, cdp, img, min_pixels)
            log.info("pixels per group: %s", result["pixels"])
        result["ok"] = bool(result["timeline"] and img is not None
                            and (not groups or min(result["pixels"].values()) >= min_pixels))
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
