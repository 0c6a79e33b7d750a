"""Headless recording: a decodable, non-blank, deterministic mp4 that shows the target turn yellow."""

import subprocess
import sys

import imageio.v2 as imageio
import mujoco
import numpy as np
import pytest

from mjendo.baseline import DLSController
from mjendo.config import ConfigError
from mjendo.envs import EndoscopeEnv
from mjendo.rollout import run
from mjendo.viewer import record


def project(point: np.ndarray, model: mujoco.MjModel, data: mujoco.MjData, camera: str,
            width: int, height: int) -> tuple[float, float]:
    """Pixel (column, row) of a world point in a fixed camera's image."""
    cam = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera)
    pos, rot = data.cam_xpos[cam], data.cam_xmat[cam].reshape(3, 3)
    p = rot.T @ (point - pos)  # camera frame: x right, y up, looking along -z
    f = 0.5 * height / np.tan(np.radians(model.cam_fovy[cam]) / 2)
    return width / 2 + f * p[0] / -p[2], height / 2 - f * p[1] / -p[2]


def frames(path):
    with imageio.get_reader(str(path)) as r:
        return np.stack([f for f in r])  # list(r) trusts len(r), which is inf for ffmpeg


@pytest.fixture(scope="module")
def reachable_targets():
    """The first three targets of FE's list (every 7th) the baseline reaches in free space."""
    env = EndoscopeEnv("FE", max_steps=80)
    ctrl = DLSController(env.task)
    found = [t for t in env.task.targets.tolist()[::7][:40] if run(env, ctrl, target=t)[0]["is_success"]][:3]
    if not found:
        pytest.fail("the baseline reached no free-space target")
    return found


@pytest.fixture(scope="module")
def reachable_target(reachable_targets):
    return reachable_targets[0]


def _yellow(frame, r0, c0):
    """Yellow pixels in a 9 x 9 window around pixel (row r0, column c0)."""
    w = frame[r0 - 4:r0 + 5, c0 - 4:c0 + 5].reshape(-1, 3).astype(int)
    return int(np.sum((w[:, 0] > 170) & (w[:, 1] > 130) & (w[:, 2] < 110)))


def test_recording_shows_the_target_turn_yellow(tmp_path, reachable_targets):
    # Pixel at the target's projection: white at the start, yellow at the end. The tip, within 3 mm of the
    # marker at the end, may hide all of it from the external camera, so one of three recordings must show it.
    shown = []
    for target in reachable_targets:
        out = tmp_path / f"ok{target}.mp4"
        r = record(out, policy="baseline", env_name="FE", episodes=1, camera="external", width=320, height=240,
                   fps=10, target=target)
        assert r["successes"] == 1
        v = frames(out)
        assert v.shape[1:] == (240, 320, 3) and len(v) == r["frames"]
        assert v.std() > 10  # not blank
        env = EndoscopeEnv("FE")
        env.reset(seed=0, options={"target_index": target})
        col, row = project(env.task.target_pos(), env.task.sim.model, env.task.sim.data, "external", 320, 240)
        r0, c0 = int(round(row)), int(round(col))
        assert np.median(v[0, r0 - 1:r0 + 2, c0 - 1:c0 + 2].reshape(-1, 3), axis=0).min() > 200  # white
        assert _yellow(v[0], r0, c0) == 0
        shown.append(_yellow(v[-1], r0, c0) >= 2)
    assert any(shown), shown


def test_same_seed_same_frames(tmp_path):
    a, b = tmp_path / "a.mp4", tmp_path / "b.mp4"
    for p in (a, b):
        record(p, policy="random", env_name="DE", episodes=1, camera="both", width=160, height=120, fps=10,
               max_steps=8, seed=3)
    fa, fb = frames(a), frames(b)
    assert fa.shape == fb.shape == (1 + 8 + 5, 120, 320, 3)
    np.testing.assert_array_equal(fa, fb)


def test_bad_output_camera_and_policy(tmp_path):
    with pytest.raises(ConfigError, match="missing or read-only"):
        record(tmp_path / "nowhere" / "x.mp4", policy="random", env_name="FE", episodes=1)
    with pytest.raises(ConfigError, match="must end in .mp4"):
        record(tmp_path / "x.avi", policy="random", env_name="FE", episodes=1)
    with pytest.raises(ConfigError, match="unknown camera"):
        record(tmp_path / "x.mp4", policy="random", env_name="FE", episodes=1, camera="belly")
    res = subprocess.run([sys.executable, "-m", "mjendo.viewer", "--headless", "--record", str(tmp_path / "y.mp4"),
                          "--policy", "Q"], capture_output=True, text=True)
    assert res.returncode == 2 and "unknown policy 'Q'" in res.stderr


@pytest.mark.parametrize("args,message", [
    (["--episodes", "0"], "--episodes must be a whole number in [1,"),
    (["--episodes", "-1"], "--episodes must be"),
    (["--width", "0"], "--width must be"),
    (["--width", "100000"], "--width must be"),
    (["--fps", "-5"], "--fps must be"),
    (["--seed", "-1"], "--seed must be"),
])
def test_viewer_refuses_arguments_that_would_write_nothing(tmp_path, args, message):
    out = tmp_path / "v.mp4"
    res = subprocess.run([sys.executable, "-m", "mjendo.viewer", "--headless", "--record", str(out), "--policy",
                          "random", *args], capture_output=True, text=True)
    assert res.returncode == 2 and message in res.stderr and "Traceback" not in res.stderr
    assert "wrote" not in res.stdout and not out.exists()


def test_interactive_without_a_display_says_how_to_record(monkeypatch, capsys):
    from mjendo import viewer

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert viewer.main(["--policy", "random"]) == 2
    err = capsys.readouterr().err
    assert "no display" in err and "--headless --record out.mp4" in err and "GLFW" not in err


def test_caption_scales_with_the_frame():
    from mjendo.viewer import caption

    def box_height(h):
        frame = np.full((h, h * 4 // 3, 3), 200, np.uint8)
        out = caption(frame, ["DE  step  10  t  0.30 s", "distance  12.0 mm"])
        dark = np.flatnonzero((out[:, 2] < 20).all(axis=1))
        return dark.max() - dark.min() + 1

    small, large = box_height(240), box_height(960)
    assert small >= 20 and large / small == pytest.approx(4.0, rel=0.25)


def test_episode_time_restarts_and_a_success_is_held(tmp_path, reachable_target, monkeypatch):
    from mjendo import viewer

    times = []
    original = viewer.Recorder.frame

    def spy(self, info, episode_time):
        times.append((info.get("step", 0), episode_time))
        return original(self, info, episode_time)

    monkeypatch.setattr(viewer.Recorder, "frame", spy)
    fps = 10
    r = record(tmp_path / "two.mp4", policy="baseline", env_name="FE", episodes=2, camera="external", width=160,
               height=120, fps=fps, target=reachable_target)
    starts = [t for step, t in times if step == 0]
    assert starts == [0.0, 0.0]  # each episode's clock starts at 0
    assert r["successes"] == 2
    # Every success stays on screen for SUCCESS_HOLD_S: rendered frames + held copies of the last one.
    assert r["frames"] == len(times) + 2 * round(viewer.SUCCESS_HOLD_S * fps)


def test_tip_camera_shows_the_wall_lit_by_the_tip_light_not_a_giant_target(reachable_target):
    import mujoco

    from mjendo.viewer import Recorder

    env = EndoscopeEnv("DE", max_steps=80)
    m = env.task.sim.model
    light = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_LIGHT, "tip_light")
    assert light >= 0 and m.light_bodyid[light] == env.task.sim.tip_body
    env.reset(seed=0)
    # Put the target right in front of the tip, as at the end of a successful approach.
    env.task.sim.set_target_marker(env.task.sim.tip_pos() + 0.004 * env.task.sim.tip_axis())
    rec = Recorder(env, "both", 160, 120)
    frame = rec.frame({"step": 0}, 0.0)
    rec.close()
    tip_pane = frame[:, 160:]
    white = np.mean(tip_pane.min(axis=2) > 235)
    assert white < 0.05, f"{white:.0%} of the tip view is white"
    assert tip_pane.std() > 5  # not blank: the lit wall shows


def test_no_opengl_backend_names_what_to_install(tmp_path, monkeypatch, capsys):
    from mjendo import viewer

    def no_context(*args, **kwargs):
        raise mujoco.FatalError("gladLoadGL error")  # what mujoco.Renderer raises without a usable OpenGL

    monkeypatch.setattr(viewer.mujoco, "Renderer", no_context)
    out = tmp_path / "v.mp4"
    assert viewer.main(["--headless", "--record", str(out), "--policy", "random", "--env", "FE"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: no OpenGL backend for headless rendering: install EGL") and "libosmesa6" in err
    assert "gladLoadGL" in err and not out.exists()
