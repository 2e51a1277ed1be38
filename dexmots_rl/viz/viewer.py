"""``dexmots-view``: replay a DexMOTS MCAP recording in the browser (viser).

    dexmots-view run.mcap                      # http://127.0.0.1:8080
    dexmots-view run.mcap --port 0             # any free port (printed)
    dexmots-view run.mcap --live               # follow a recording that a running job rewrites

The page has a timeline slider, play/pause, a speed factor, a world selector (all worlds on a grid, or
one), the goal ghost (the object at its goal pose, translucent), arrows at the object for the actual
(red force, orange torque) and target (green force, blue torque) wrench, sized by the scene, a readout of
the frame, and a reward plot (one line per world, or the reward and its terms for one world). Every body
the recording carries is drawn (the hand's links and palm, each of the object's bodies, the table:
:mod:`~dexmots_rl.recording.geometry`), each mesh as one batched mesh (instances = worlds), so a frame
costs a handful of messages however many worlds there are. The first view frames the hand and the
object (their bounding box at the first frame), seen from ``camera_direction``.

``--live`` polls the file (every ``--poll`` seconds) and reloads it whenever it changes, following the
newest frame while playing or parked on the last frame. It works with recordings that are rewritten
whole and atomically: :class:`~dexmots_rl.viz.EpisodeRecorder` with ``live=True`` (``dexmots-record
... live=true``) rewrites its file after every episode. There is no streaming of half-written files.

A port that is taken is an error (viser itself would silently move to the next port).

Example:
    >>> import os, tempfile
    >>> from dexmots_rl.envs import make_env
    >>> from dexmots_rl.recording import EpisodeRecorder
    >>> env = make_env("screw_claw", num_envs=2, differentiable=False, seed=0)
    >>> path = os.path.join(tempfile.mkdtemp(), "run.mcap")
    >>> with EpisodeRecorder(path, env) as rec:
    ...     rec.record_rollout(env.rollout(3, tensordict=env.reset(), auto_reset=False,
    ...                                  break_when_any_done=False))
    >>> viewer = ReplayViewer(path, port=0)
    >>> viewer.set_frame(2); viewer.frame
    2
    >>> viewer.stop()
"""

from __future__ import annotations

import argparse
import contextlib
import io
import logging
import os
import socket
import sys
import threading
import time
from pathlib import Path

import numpy as np

from ..recording.format import Recording, RecordingFormatError
from ..recording.geometry import GOAL_RGBA, STATIC
from ..recording.reader import read_recording
from ..recording.recorder import FORCE_SCALE, TORQUE_SCALE
from ..recording.scene_messages import arrow_scales, arrow_segments, arrow_style

__all__ = ["PortInUseError", "check_port_free", "ReplayViewer", "main"]

log = logging.getLogger(__name__)

PALETTE = ("#e6194b", "#3cb44b", "#4363d8", "#f58231", "#911eb4", "#42d4f4", "#f032e6", "#9a6324")
ARROW_COLORS = np.array([[230, 50, 50], [50, 205, 50], [240, 150, 25], [50, 150, 240]], dtype=np.uint8)
MAX_PLOTTED_WORLDS = 8
CAMERA_DIRECTION = (0.35, -1.0, 0.6)  # the first view: from the front right of the hand (fingers along +x), above
CAMERA_MARGIN = 0.9  # the framed bounding sphere's radius times this fills the view's height (its corners may be cut)


class PortInUseError(OSError):
    """The requested port is already taken on that host."""


def check_port_free(host: str, port: int) -> None:
    """Raise :class:`PortInUseError` if something already listens on ``host:port`` (``port=0``: any port, fine)."""
    if port == 0:
        return
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except socket.gaierror as exc:
        raise OSError(f"cannot resolve host {host!r}: {exc}") from None
    for family, kind, proto, _, addr in infos:
        with socket.socket(family, kind, proto) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # what the server itself will use
            try:
                s.bind(addr)
            except OSError as exc:
                raise PortInUseError(f"port {port} on {host} is already in use ({exc.strerror}); choose another "
                                     "with --port N, or --port 0 for any free port") from None


def _rgb(rgba) -> tuple[int, int, int]:
    return tuple(int(round(255 * c)) for c in rgba[:3])


def _nice(x: float) -> float:
    """``x`` rounded down to 1, 2 or 5 times a power of ten (grid cell sizes)."""
    p = 10.0 ** np.floor(np.log10(x))
    return float(max(m for m in (1, 2, 5) if m * p <= x) * p)


class ReplayViewer:
    """A viser server replaying ``recording`` (a path or a :class:`~dexmots_rl.viz.Recording`); see the module
    docstring. ``shadows=False`` makes software rendering (headless browsers) much faster;
    ``camera_direction``: from the scene's centre toward the first view's camera (world frame)."""

    def __init__(self, recording: str | os.PathLike | Recording, host: str = "127.0.0.1", port: int = 8080,
                 live: bool = False, poll_s: float = 0.5, shadows: bool = True,
                 camera_direction=CAMERA_DIRECTION):
        import viser

        self.path = None if isinstance(recording, Recording) else Path(recording)
        self._stat = self._file_stat()  # before reading: a change while we read is seen by the poller
        rec = recording if isinstance(recording, Recording) else None
        if rec is None and not (live and not self.path.exists()):
            rec = read_recording(self.path)
        check_port_free(host, port)
        with contextlib.redirect_stdout(io.StringIO()):  # viser prints a banner; we log the URL instead
            self.server = viser.ViserServer(host=host, port=port, verbose=False)
        if port and self.server.get_port() != port:  # lost a race for the port: viser moved on
            self.server.stop()
            raise PortInUseError(f"port {port} on {host} is already in use; choose another with --port")
        self.host, self.port = host, self.server.get_port()
        log.info("viewer at %s", self.url)
        self.shadows, self.live = shadows, live
        self.camera_direction = np.asarray(camera_direction, dtype=np.float64)
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._playing = False
        self._handles: dict = {}
        self.rec: Recording | None = None
        self._build_gui()
        if rec is not None:
            self._load(rec)
        self._threads = [threading.Thread(target=self._play_loop, daemon=True, name="dexmots-view-play")]
        if live:
            self._threads.append(threading.Thread(target=self._poll_loop, args=(poll_s,), daemon=True,
                                                  name="dexmots-view-live"))
        for t in self._threads:
            t.start()

    # ------------------------------------------------------------------------------------------ api
    @property
    def url(self) -> str:
        """The address it serves on, as given (``0.0.0.0``: every interface of this machine, reachable from
        others by its name or address)."""
        host = self.host or "0.0.0.0"
        return f"http://[{host}]:{self.port}/" if ":" in host else f"http://{host}:{self.port}/"

    @property
    def frame(self) -> int:
        return int(self._gui["frame"].value)

    def set_frame(self, frame: int) -> None:
        """Show frame ``frame`` (clamped to the recording)."""
        if self.rec is not None:
            self._gui["frame"].value = int(min(max(frame, 0), self.rec.num_frames - 1))

    def serve_forever(self) -> None:
        try:
            while not self._stop.is_set():
                time.sleep(0.5)
        except KeyboardInterrupt:
            pass
        finally:
            self.stop()

    def stop(self) -> None:
        self._stop.set()
        with contextlib.redirect_stdout(io.StringIO()):
            self.server.stop()

    # ------------------------------------------------------------------------------------------ gui
    def _build_gui(self) -> None:
        gui = self.server.gui
        self._gui = {
            "frame": gui.add_slider("Frame", min=0, max=1, step=1, initial_value=0),
            "play": gui.add_button("Play"),
            "speed": gui.add_slider("Speed (x real time)", min=0.1, max=4.0, step=0.1, initial_value=1.0),
            "world": gui.add_dropdown("World", options=("all",), initial_value="all"),
            "goal": gui.add_checkbox("Goal ghost", initial_value=True),
            "wrench": gui.add_checkbox("Wrench arrows", initial_value=True),
            "info": gui.add_markdown("no recording loaded yet"),
        }
        self._gui["frame"].on_update(lambda _: self._show())
        self._gui["play"].on_click(lambda _: self._toggle_play())
        self._gui["world"].on_update(lambda _: self._on_world())
        self._gui["goal"].on_update(lambda _: self._show())
        self._gui["wrench"].on_update(lambda _: self._show())
        self._plot = None

    def _toggle_play(self) -> None:
        self._playing = not self._playing
        self._gui["play"].label = "Pause" if self._playing else "Play"

    def _worlds(self) -> list[int]:
        sel = self._gui["world"].value
        return list(range(self.rec.num_worlds)) if sel == "all" else [int(sel)]

    def _on_world(self) -> None:
        with self._lock:
            self._update_plot()
            self._show()

    # ------------------------------------------------------------------------------------- loading
    def _load(self, rec: Recording) -> None:
        with self._lock:
            first = self.rec is None
            same_scene = not first and rec.meta.get("body_names") == self.rec.meta.get("body_names") \
                and rec.num_worlds == self.rec.num_worlds
            self.rec = rec
            frames = rec.frames
            pose = frames["body_pose"].double().numpy()  # [F, N, B, 7]
            self._pos, self._quat = pose[..., :3], pose[..., 3:]
            goal = frames["goal_pose"].double().numpy()
            self._goal_pos, self._goal_quat = goal[..., :3], goal[..., 3:]
            self._wrench = frames["object", "wrench"].double().numpy()
            self._target = frames["target_wrench"].double().numpy()
            self._offsets = rec.world_offsets.double().numpy()
            self._style = arrow_style(rec.geometry, pose[0, 0])
            self._scales = arrow_scales(self._style, np.concatenate([self._wrench, self._target]), (
                float(rec.meta.get("force_scale", FORCE_SCALE)), float(rec.meta.get("torque_scale", TORQUE_SCALE))))
            if not same_scene:
                self._build_scene(rec)
                self._gui["goal"].value = rec.meta.get("goal", "true") == "true"  # no goal: no ghost
            slider = self._gui["frame"]
            follow = first or self._playing or slider.value >= slider.max
            slider.max = max(rec.num_frames - 1, 1)
            self._update_plot()
            if follow:
                slider.value = 0 if first and not self.live else rec.num_frames - 1
            self._show()

    def _build_scene(self, rec: Recording) -> None:
        scene, g = self.server.scene, rec.geometry
        for handle in self._handles.values():
            handle.remove()
        self._handles = {}
        m = rec.num_worlds
        ident, zeros = np.tile([1.0, 0, 0, 0], (m, 1)), np.zeros((m, 3))
        for k, part in enumerate(g.parts):  # static parts sit at each world's offset, in its frame
            self._handles[f"part{k}"] = scene.add_batched_meshes_simple(
                f"/worlds/{part.role}/{k}", part.vertices, part.faces, ident,
                self._offsets if part.body == STATIC else zeros, batched_colors=_rgb(part.rgba),
                flat_shading=part.role in ("object", "base", "table"), lod="off",
                cast_shadow=part.role != "table")
        self._handles["goal"] = scene.add_batched_meshes_simple(
            "/worlds/goal", g.ghost_vertices, g.ghost_faces, ident, zeros, batched_colors=_rgb(GOAL_RGBA),
            opacity=GOAL_RGBA[3], flat_shading=True, lod="off", cast_shadow=False)
        style = self._style
        self._handles["arrows"] = scene.add_arrows("/worlds/wrench", np.zeros((4 * m, 2, 3)),
                                                   np.tile(ARROW_COLORS, (m, 1)), shaft_radius=style.shaft_radius,
                                                   head_radius=style.head_radius, head_length=style.head_length)
        self._frame_camera(rec)
        self._gui["world"].options = ("all", *[str(w) for w in range(rec.num_worlds)])
        self._gui["world"].value = "all" if rec.num_worlds <= 16 else "0"
        scene.configure_default_lights(enabled=True, cast_shadow=self.shadows)
        scene.configure_environment_map("warehouse", environment_intensity=0.2)

    def _frame_camera(self, rec: Recording) -> None:
        """Point the first view at the hand and the object of every world (first frame), and lay the grid under."""
        g = rec.geometry
        pts = np.concatenate([g.world_points(np.concatenate([self._pos[0, w], self._quat[0, w]], -1)) + self._offsets[w]
                              for w in range(rec.num_worlds)])
        lo, hi = pts.min(0), pts.max(0)
        look, radius = 0.5 * (lo + hi), max(0.5 * float(np.linalg.norm(hi - lo)), 1e-3)
        cam = self.server.initial_camera
        distance = CAMERA_MARGIN * radius / np.sin(0.5 * cam.fov)
        view = self.camera_direction / np.linalg.norm(self.camera_direction)
        cam.look_at = look
        cam.position = look + distance * view
        table = [p for p in g.parts if p.role == "table"]
        floor = min([lo[2]] + [float(p.vertices[:, 2].min()) for p in table]) - 1e-3
        self._handles["grid"] = self.server.scene.add_grid(
            "/grid", width=8 * radius, height=8 * radius, cell_size=_nice(radius / 2), section_size=_nice(2 * radius),
            position=(look[0], look[1], floor))

    def _update_plot(self) -> None:
        rec = self.rec
        worlds = self._worlds()
        x = rec.time.numpy().astype(np.float64)
        reward = rec.frames["reward"][..., 0].double().numpy()  # [F, N]
        if len(worlds) == 1:
            w = worlds[0]
            ys = [reward[:, w]] + [rec.frames["reward_terms", t][:, w, 0].double().numpy() for t in rec.reward_terms]
            labels = ["reward"] + list(rec.reward_terms)
        else:
            shown = worlds[:MAX_PLOTTED_WORLDS]
            ys, labels = [reward[:, w] for w in shown], [f"world {w}" for w in shown]
        from viser import uplot

        series = (uplot.Series(label="time [s]"),
                  *[uplot.Series(label=lab, stroke=PALETTE[k % len(PALETTE)], width=2) for k, lab in enumerate(labels)])
        data = (x, *ys)
        if self._plot is not None and len(self._plot.series) == len(series):
            self._plot.series, self._plot.data = series, data
            return
        if self._plot is not None:
            self._plot.remove()
        self._plot = self.server.gui.add_uplot(data, series, title="reward", scales={"x": {"time": False}},
                                               aspect=1.6)

    # -------------------------------------------------------------------------------------- drawing
    def _show(self) -> None:
        if self.rec is None or "goal" not in self._handles:
            return
        with self._lock:
            f = int(min(self._gui["frame"].value, self.rec.num_frames - 1))
            worlds = self._worlds()
            off = self._offsets[worlds] if len(worlds) > 1 else self._offsets.mean(0, keepdims=True)
            with self.server.atomic():
                for k, part in enumerate(self.rec.geometry.parts):
                    h = self._handles[f"part{k}"]
                    if part.body == STATIC:
                        h.batched_positions = off.astype(np.float32)
                        h.batched_wxyzs = np.tile([1.0, 0, 0, 0], (len(off), 1)).astype(np.float32)
                    else:
                        h.batched_positions = (self._pos[f, worlds, part.body] + off).astype(np.float32)
                        h.batched_wxyzs = self._quat[f, worlds, part.body].astype(np.float32)
                goal = self._handles["goal"]
                goal.visible = bool(self._gui["goal"].value)
                goal.batched_positions = (self._goal_pos[f, worlds] + off).astype(np.float32)
                goal.batched_wxyzs = self._goal_quat[f, worlds].astype(np.float32)
                arrows = self._handles["arrows"]
                points, colors = self._arrow_points(f, worlds, off)
                arrows.visible = bool(self._gui["wrench"].value) and len(points) > 0
                if len(points):  # an arrow of no length would still draw its head: left out
                    arrows.colors, arrows.points = colors, points
            self._gui["info"].content = self._readout(f, worlds)

    def _arrow_points(self, f: int, worlds: list[int], off: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Start and end [K, 2, 3] and colours [K, 3] of the arrows longer than their heads (a shorter one would
        show as a loose cone), at the recording's scales (:func:`.arrow_scales`)."""
        force_scale, torque_scale = self._scales
        base = self.rec.geometry.num_hand_links
        pose = np.concatenate([self._pos[f, worlds, base] + off, self._quat[f, worlds, base]], -1)  # [M, 7]
        vecs = np.stack([self._wrench[f, worlds, :3] * force_scale, self._target[f, worlds, :3] * force_scale,
                         self._wrench[f, worlds, 3:] * torque_scale, self._target[f, worlds, 3:] * torque_scale], 1)
        pts = arrow_segments(self._style, pose[:, None], vecs).reshape(-1, 2, 3)
        keep = np.linalg.norm(pts[:, 1] - pts[:, 0], axis=-1) > self._style.head_length
        return pts[keep].astype(np.float32), np.tile(ARROW_COLORS, (len(worlds), 1))[keep]

    def _readout(self, f: int, worlds: list[int]) -> str:
        fr = self.rec.frames[f]
        reward, success = fr["reward"][worlds, 0], fr["success"][worlds, 0]
        lines = [f"**episode** {int(self.rec.episode[f])} &nbsp; **frame** {f + 1}/{self.rec.num_frames} &nbsp; "
                 f"**t** {float(self.rec.time[f]):.3f} s"]
        if len(worlds) == 1:
            w = worlds[0]
            q = fr["object", "q"][w].tolist()
            lines.append(f"**step** {int(fr['task', 'step'][w, 0])} &nbsp; **reward** {float(reward[0]):.3f} &nbsp; "
                         f"**success** {bool(success[0])}")
            lines.append("**object q** " + ", ".join(f"{v:.3f}" for v in q) + " &nbsp; **goal** "
                         + ", ".join(f"{v:.3f}" for v in fr["task", "goal"][w].tolist()))
            for name in self.rec.reward_terms:
                lines.append(f"- {name}: {float(fr['reward_terms', name][w, 0]):.3f}")
        else:
            lines.append(f"**mean reward** {float(reward.mean()):.3f} &nbsp; **success** "
                         f"{int(success.sum())}/{len(worlds)}")
        return "\n\n".join(lines)

    # ------------------------------------------------------------------------------------- threads
    def _play_loop(self) -> None:
        last, acc = time.perf_counter(), 0.0
        while not self._stop.wait(1 / 60):
            now = time.perf_counter()
            elapsed, last = now - last, now
            if not self._playing or self.rec is None:
                acc = 0.0
                continue
            dt = float(self.rec.meta.get("dt", 1 / 60))
            acc += elapsed * float(self._gui["speed"].value) / dt
            if acc >= 1.0:
                steps, acc = int(acc), acc - int(acc)
                nxt = self.frame + steps
                self.set_frame(nxt if nxt < self.rec.num_frames else 0)

    def _file_stat(self):
        try:
            st = os.stat(self.path)
            return st.st_mtime_ns, st.st_size
        except (OSError, TypeError):
            return None

    def _poll_loop(self, poll_s: float) -> None:
        if self.rec is None:
            log.info("waiting for %s to appear", self.path)
        while not self._stop.wait(poll_s):
            stat = self._file_stat()
            if stat is None or stat == self._stat:
                continue
            try:
                rec = read_recording(self.path)
            except RecordingFormatError as exc:  # should not happen with atomic writers; try again later
                log.warning("live reload failed: %s", exc)
                continue
            self._stat = stat
            self._load(rec)
            log.info("reloaded %s: %d frames", self.path, rec.num_frames)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="dexmots-view", description=__doc__.splitlines()[0])
    p.add_argument("recording", help="an MCAP file written by dexmots-record / EpisodeRecorder")
    p.add_argument("--port", type=int, default=8080, help="0 picks any free port")
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--live", action="store_true", help="reload the file whenever it changes (see the docs)")
    p.add_argument("--poll", type=float, default=0.5, help="seconds between checks of the file with --live")
    args = p.parse_args(argv)
    if not 0 <= args.port <= 65535:  # before loading anything: viser would fail late, deep in asyncio
        p.exit(2, f"dexmots-view: --port must be in 0..65535 (0: any free port), got {args.port}\n")
    if not (args.poll > 0 and args.poll < float("inf")):
        p.exit(2, f"dexmots-view: --poll must be a positive number of seconds, got {args.poll}\n")
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="%(asctime)s %(message)s")
    try:
        viewer = ReplayViewer(args.recording, host=args.host, port=args.port, live=args.live, poll_s=args.poll)
    except (RecordingFormatError, OSError) as exc:
        raise SystemExit(f"dexmots-view: {exc}") from None
    print(f"dexmots-view: serving {args.recording} at {viewer.url}", flush=True)
    viewer.serve_forever()


if __name__ == "__main__":
    main()
