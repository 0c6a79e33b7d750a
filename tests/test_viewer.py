"""Headless recording: a decodable, non-blank, deterministic mp4 that shows the target turn yellow."""

import subprocess
import sys

import imageio.v2 as imageio
import numpy as np
import pytest

from mjendo.baseline import DLSController
from mjendo.config import ConfigError
from mjendo.envs import EndoscopeEnv
from mjendo.rollout import run
from mjendo.viewer import project, record


def frames(path):
    with imageio.get_reader(str(path)) as r:
        return np.stack([f for f in r])  # list(r) trusts len(r), which is inf for ffmpeg


@pytest.fixture(scope="module")
def reachable_target():
    """A list-A target the baseline reaches in free space (FE), found by trying them in order."""
    env = EndoscopeEnv("FE", max_steps=80)
    ctrl = DLSController(env.task)
    for t in env.task.stomach.info["free_reachable_targets"]:
        if t in set(env.task.targets.tolist()) and run(env, ctrl, target=t)[0]["is_success"]:
            return t
    pytest.fail("the baseline reached no free-space target")


def test_recording_shows_the_target_turn_yellow(tmp_path, reachable_target):
    out = tmp_path / "ok.mp4"
    r = record(out, policy="baseline", env_name="FE", episodes=1, camera="external", width=320, height=240,
               fps=10, target=reachable_target)
    assert r["successes"] == 1
    v = frames(out)
    assert v.shape[1:] == (240, 320, 3) and len(v) == r["frames"]
    assert v.std() > 10  # not blank
    # Pixel at the target's projection: white at the start, yellow at the end.
    env = EndoscopeEnv("FE")
    env.reset(seed=0, options={"target_index": reachable_target})
    col, row = project(env.task.target_pos(), env.task.sim.model, env.task.sim.data, "external", 320, 240)
    r0, c0 = int(round(row)), int(round(col))

    def yellow(frame):
        w = frame[r0 - 4:r0 + 5, c0 - 4:c0 + 5].reshape(-1, 3).astype(int)
        return int(np.sum((w[:, 0] > 170) & (w[:, 1] > 130) & (w[:, 2] < 110)))

    assert np.median(v[0, r0 - 1:r0 + 2, c0 - 1:c0 + 2].reshape(-1, 3), axis=0).min() > 200  # white
    assert yellow(v[0]) == 0 and yellow(v[-1]) >= 2  # the tip hides part of it, not all


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
