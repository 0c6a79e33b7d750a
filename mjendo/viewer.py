"""Watch, record and drive the endoscope.

    python -m mjendo.viewer --headless --record out.mp4        # policy E in DE, 3 episodes
    python -m mjendo.viewer --headless --record a.mp4 --policy A --env SE --camera both
    python -m mjendo.viewer                                    # interactive window (needs a display)

Frames show the stomach translucent, the per-contact forces and their
resultant as arrows, the target white until the tip is within 3 mm and then
yellow, and a caption with step, distance (mm), resultant force (N) and
success. Interactive keys: I/K pull cable +x/-x, J/L cable +y/-y, U/O insert /
withdraw, R reset, P toggle the policy.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import mujoco
import numpy as np

import mjendo  # noqa: F401  (chooses the GL backend first)
from mjendo import cli, rollout
from mjendo.config import CURRENT_VERSION, FIDELITIES, ConfigError
from mjendo.endoscope import TIP_CAMERA
from mjendo.envs import EndoscopeEnv
from mjendo.gl import NO_GL_HELP, NoOpenGLError
from mjendo.policies import PolicyError, load_controller, obs_options_of, version_of
from mjendo.scene import BACKDROP_GROUP
from mjendo.task import NavigationTask

CAMERA_NAMES = {"external": "external", "tip": TIP_CAMERA}
STOMACH_ALPHA = 0.3
RESULTANT_RGBA = np.array([1.0, 0.2, 0.1, 1.0], np.float32)
ARROW_M_PER_N = 0.02  # 1 N of resultant force draws a 20 mm arrow


def style(model: mujoco.MjModel) -> None:
    """Translucent stomach so the endoscope inside shows; contact arrows at ARROW_M_PER_N.

    MuJoCo draws a force f as f * map.force / stat.meanmass metres long, and
    the light flex bodies make meanmass tiny, so the scale is set from it.
    """
    if model.nflex:
        model.flex_rgba[:, 3] = STOMACH_ALPHA
    model.vis.map.force = ARROW_M_PER_N * model.stat.meanmass


def add_resultant_arrow(scene: mujoco.MjvScene, task: NavigationTask) -> None:
    """Resultant contact force on the endoscope, drawn from the tip."""
    f = task.contact.force if task.contact is not None else np.zeros(3)
    n = float(np.linalg.norm(f))
    if n < 1e-3 or scene.ngeom >= scene.maxgeom:
        return
    start = task.sim.tip_pos()
    end = start + f * ARROW_M_PER_N
    g = scene.geoms[scene.ngeom]
    mujoco.mjv_initGeom(g, mujoco.mjtGeom.mjGEOM_ARROW, np.zeros(3), np.zeros(3), np.zeros(9), RESULTANT_RGBA)
    mujoco.mjv_connector(g, mujoco.mjtGeom.mjGEOM_ARROW, 0.003, start, end)
    scene.ngeom += 1


def scene_option() -> mujoco.MjvOption:
    opt = mujoco.MjvOption()
    opt.flags[mujoco.mjtVisFlag.mjVIS_CONTACTFORCE] = True
    for g in (0, 1, 2, BACKDROP_GROUP):
        opt.geomgroup[g] = True
    opt.sitegroup[:] = [1, 1, 1, 0, 0, 0]  # hide cable routing sites
    return opt


def _font(size: int):
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)  # scalable with FreeType
    except (TypeError, OSError):
        return ImageFont.load_default()


def caption(frame: np.ndarray, lines: list[str], corner: str = "bottom-left") -> np.ndarray:
    """Text box scaled to the frame (about 1/28 of its height per line), bottom-left or top-left."""
    from PIL import Image, ImageDraw

    lines = [ln for ln in lines if ln]
    if not lines:
        return frame
    img = Image.fromarray(frame)
    draw = ImageDraw.Draw(img)
    size = max(10, frame.shape[0] // 28)
    font = _font(size)
    pad, h = size // 3, int(size * 1.25)
    width = 2 * pad + max(int(draw.textlength(ln, font=font)) for ln in lines)
    top = frame.shape[0] - pad - h * len(lines) if corner == "bottom-left" else pad
    draw.rectangle([0, top - pad, width, top + h * len(lines) + pad // 2], fill=(0, 0, 0))
    for i, line in enumerate(lines):
        colour = (255, 220, 0) if line.startswith("SUCCESS") else (255, 255, 255)
        draw.text((pad, top + h * i), line, fill=colour, font=font)
    return np.asarray(img)


PANE_TITLES = {"external": "external view", TIP_CAMERA: "tip camera (light at the tip)"}


class Recorder:
    """Renders an env's frames (one or two cameras) with overlays and captions."""

    def __init__(self, env: EndoscopeEnv, camera: str, width: int, height: int):
        if camera not in (*CAMERA_NAMES, "both"):
            raise ConfigError(f"unknown camera {camera!r}; valid: external, tip, both")
        self.env, self.width, self.height = env, width, height
        self.cams = [CAMERA_NAMES[c] for c in (("external", "tip") if camera == "both" else (camera,))]
        style(env.task.sim.model)
        try:
            self.renderer = mujoco.Renderer(env.task.sim.model, height, width)
        except Exception as exc:
            raise NoOpenGLError(f"{NO_GL_HELP} (renderer failed: {exc})") from exc
        self.option = scene_option()
        self.tip_option = scene_option()
        self.tip_option.flags[mujoco.mjtVisFlag.mjVIS_CONTACTFORCE] = False
        self.tip_option.geomgroup[BACKDROP_GROUP] = False
        self.tip_option.sitegroup[:] = 0
        self.tip_option.tendongroup[:] = 0
        flags = self.renderer.scene.flags
        for flag in (mujoco.mjtRndFlag.mjRND_SHADOW, mujoco.mjtRndFlag.mjRND_REFLECTION,
                     mujoco.mjtRndFlag.mjRND_SKYBOX):
            flags[flag] = False  # software rendering: these cost most and show least

    def _view(self, cam: str) -> np.ndarray:
        task = self.env.task
        if cam != TIP_CAMERA:
            self.renderer.update_scene(task.sim.data, camera=cam, scene_option=self.option)
            add_resultant_arrow(self.renderer.scene, task)
            return self.renderer.render()
        # What the scope's own camera sees: an opaque wall lit by the tip light; no target marker (it would
        # fill the view near the wall), tip marker, cables, force arrows or backdrop.
        m = task.sim.model
        alpha = m.flex_rgba[:, 3].copy()
        m.flex_rgba[:, 3] = 1.0
        try:
            self.renderer.update_scene(task.sim.data, camera=cam, scene_option=self.tip_option)
        finally:
            m.flex_rgba[:, 3] = alpha
        return self.renderer.render()

    def frame(self, info: dict, episode_time: float) -> np.ndarray:
        task = self.env.task
        f = float(np.linalg.norm(info.get("force_N", np.zeros(3))))
        lines = [f"{task.cfg.env}  step {info.get('step', 0):3d}  t {episode_time:5.2f} s",
                 f"distance {info.get('distance_mm', task.distance_mm()):5.1f} mm",
                 f"force {f:5.2f} N" + (" contact" if info.get("contact") else ""),
                 "SUCCESS: within 3 mm" if info.get("is_success") else ""]
        views = [self._view(c) for c in self.cams]
        if len(views) > 1:
            views = [caption(v, [PANE_TITLES[c]], corner="top-left") for v, c in zip(views, self.cams, strict=True)]
        return caption(np.concatenate(views, axis=1), lines)

    def close(self) -> None:
        self.renderer.close()


SUCCESS_HOLD_S = 1.5  # a success stays on screen this long (it happens in one control step)
END_HOLD_S = 0.5


def check_recording(episodes: int, seed: int, width: int, height: int, fps: int, max_steps: int) -> None:
    """Refuse arguments that would write an empty or unplayable video, naming the valid range."""
    checks = [("episodes", episodes, 1, 10_000), ("seed", seed, 0, 2**31 - 1), ("fps", fps, 1, 240),
              ("steps", max_steps, 1, 100_000), ("width", width, 16, EndoscopeEnv.MAX_FRAME_PIXELS),
              ("height", height, 16, EndoscopeEnv.MAX_FRAME_PIXELS)]
    for name, v, lo, hi in checks:
        if isinstance(v, bool) or not isinstance(v, int | np.integer) or not lo <= v <= hi:
            raise ConfigError(f"--{name} must be a whole number in [{lo}, {hi}], not {v!r}")


def record(path: Path, policy: str = "E", env_name: str = "DE", episodes: int = 3, seed: int = 0,
           camera: str = "external", width: int = 640, height: int = 480, fps: int = 30,
           max_steps: int = 80, target: int | None = None, fidelity: str = "fast") -> dict:
    """Record episodes of a controller to an H.264 mp4; returns counts for reporting."""
    import imageio.v2 as imageio
    from tqdm import tqdm

    check_recording(episodes, seed, width, height, fps, max_steps)
    path = Path(path)
    if path.suffix.lower() != ".mp4":
        raise ConfigError(f"output {path} must end in .mp4")
    if not path.parent.exists() or not _writable(path.parent):
        raise ConfigError(f"cannot write {path}: folder {path.parent} is missing or read-only")
    width, height = width - width % 2, height - height % 2  # H.264 needs even sizes
    env = EndoscopeEnv(env_name, **obs_options_of(policy), max_steps=max_steps, fidelity=fidelity,
                       version=version_of(policy))
    ctrl = load_controller(policy, env.task)
    rec = Recorder(env, camera, width, height)
    writer = imageio.get_writer(str(path), fps=fps, codec="libx264", pixelformat="yuv420p", quality=7,
                                macro_block_size=2, ffmpeg_log_level="error")
    frames, successes = 0, 0
    try:
        for ep in tqdm(range(episodes), desc=f"recording {path.name}", unit="episode"):
            t0 = None
            for s in rollout.episode(env, ctrl, seed=seed + ep, target=target):
                t0 = env.task.sim.time if t0 is None else t0
                image = rec.frame(s.info, env.task.sim.time - t0)
                writer.append_data(image)
                frames += 1
            successes += bool(s.info.get("is_success"))
            hold = SUCCESS_HOLD_S if s.info.get("is_success") else END_HOLD_S
            for _ in range(max(1, int(round(hold * fps)))):  # hold the last frame
                writer.append_data(image)
                frames += 1
    finally:
        writer.close()
        rec.close()
    if not path.exists() or path.stat().st_size == 0:
        raise ConfigError(f"ffmpeg wrote nothing to {path}; check the disk and the frame size")
    return {"frames": frames, "successes": successes, "episodes": episodes}


def _writable(folder: Path) -> bool:
    return os.access(folder, os.W_OK)


def interactive(policy: str, env_name: str, seed: int) -> None:
    """Window with keyboard driving (needs a display)."""
    try:
        if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
            raise RuntimeError("no display")
        import glfw
        import mujoco.viewer

        if not glfw.init():
            raise RuntimeError("GLFW cannot open a window")
    except Exception:
        raise NoOpenGLError("no display for an interactive window: record a video instead with "
                            "`python -m mjendo.viewer --headless --record out.mp4`") from None
    opts = {"force_obs": True} if policy == "keyboard" else obs_options_of(policy)
    env = EndoscopeEnv(env_name, **opts, max_steps=10**9,
                       version=CURRENT_VERSION if policy == "keyboard" else version_of(policy))
    style(env.task.sim.model)
    ctrl = load_controller(policy, env.task) if policy != "keyboard" else None
    obs, _ = env.reset(seed=seed)
    keys = {"I": (0, 0.4), "K": (1, 0.4), "J": (2, 0.4), "L": (3, 0.4), "U": (4, 0.4), "O": (4, -0.4)}
    state = {"action": np.zeros(5), "auto": ctrl is not None, "reset": False}

    def on_key(code: int) -> None:
        ch = chr(code).upper() if 0 <= code < 256 else ""
        if ch in keys:
            i, v = keys[ch]
            state["action"][i] = v
        elif ch == "R":
            state["reset"] = True
        elif ch == "P" and ctrl is not None:
            state["auto"] = not state["auto"]

    with mujoco.viewer.launch_passive(env.task.sim.model, env.task.sim.data, key_callback=on_key) as v:
        v.opt.flags[mujoco.mjtVisFlag.mjVIS_CONTACTFORCE] = True
        while v.is_running():
            if state["reset"]:
                obs, _ = env.reset()
                state["reset"] = False
            action = ctrl.act(obs, env.task) if state["auto"] else state["action"]
            obs, *_ = env.step(action)
            state["action"] = np.zeros(5)
            with v.lock():
                v.user_scn.ngeom = 0
                add_resultant_arrow(v.user_scn, env.task)
            v.sync()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m mjendo.viewer", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--headless", action="store_true", help="no window: render offscreen (needs --record)")
    ap.add_argument("--record", type=Path, help="write an mp4 here")
    ap.add_argument("--policy", default="E",
                    help="A-E (shipped), a published variant (E-paper-step), a run folder, baseline, random, keyboard")
    ap.add_argument("--env", default="DE", help="FE, SE, DE, UE1, UE2")
    ap.add_argument("--episodes", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--camera", default="external", help="external, tip or both (side by side)")
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--fps", type=int, default=30)
    ap.add_argument("--steps", type=int, default=80, help="steps per episode (paper's trials: 80)")
    ap.add_argument("--target", type=int,
                    help="a target id of the env's list (targets.json's point id; version 0: a lumen vertex)")
    ap.add_argument("--fidelity", choices=list(FIDELITIES), default="fast", help="stomach to show")
    a = ap.parse_args(argv)
    if a.headless and not a.record:
        ap.error("--headless needs --record out.mp4")

    def command() -> None:
        if a.record:
            r = record(a.record, a.policy, a.env, a.episodes, a.seed, a.camera, a.width, a.height, a.fps,
                       a.steps, a.target, a.fidelity)
            print(f"wrote {a.record}: {r['frames']} frames, {r['successes']}/{r['episodes']} episodes reached "
                  "the target")
        else:
            interactive(a.policy, a.env, a.seed)

    return cli.run(command, ConfigError, PolicyError, NoOpenGLError, ValueError)


if __name__ == "__main__":
    raise SystemExit(main())
