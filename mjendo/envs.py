"""Gymnasium environments: the navigation task (:mod:`mjendo.task`) behind ``gymnasium.Env``."""

from __future__ import annotations

import atexit
import weakref
from dataclasses import replace

import gymnasium as gym
import mujoco
import numpy as np

from mjendo import anatomy
from mjendo.config import PAPER_ACTION_LIMIT, ConfigError, TaskConfig, task_config
from mjendo.endoscope import TIP_CAMERA
from mjendo.task import NavigationTask, action_size

CAMERAS = ("external", TIP_CAMERA)
# Envs holding a renderer: closed at exit while OpenGL is still there (else EGL prints errors on teardown).
# The hook is registered after the first renderer exists, so it runs before MuJoCo's own EGL shutdown.
_RENDERING: weakref.WeakSet = weakref.WeakSet()


def _close_renderers() -> None:
    for env in list(_RENDERING):
        env.close()


class EndoscopeEnv(gym.Env):
    """Contact-aided navigation of a flexible endoscope to a target on the stomach wall.

    ## Action space

    ``Box(-0.4, 0.4, (5,), float32)``, applied every control period of 100 ms (v1; 5 physics
    steps of 20 ms in the fast stomach, 10 of 10 ms in the full one). Out-of-range values are
    clipped; NaN raises.

    | index | meaning | unit and scale (v1) |
    |---|---|---|
    | 0-3 | cables +x, -x, +y, -y of the active segment | change of cable pull, 1 unit = 1 mm (0.4: 0.4 mm per step, 4 mm/s); positive pulls, negative pays out |
    | 4 | insertion through the cardia | change of insertion depth, 1 unit = 6.25 mm (0.4: 2.5 mm per step, 25 mm/s) |

    With ``task_space=True`` (not the paper's) the action is ``Box(-0.4, 0.4, (3,))``: the tip displacement
    asked of the DLS controller (``mjendo.baseline``), world x, y, z, 1 unit = 25 mm (0.4: 10 mm); the
    controller turns it into the five commands above, within their limits.

    ## Observation space

    ``Box(low, high, (11,), (15,), with ``scope_obs`` 7 more, with ``time_obs`` 1 more, with ``phase_obs`` 2 more, with ``step_obs`` 7 more, with ``depth_obs`` 5 more, with ``normal_obs`` 3 more, with ``plan_obs`` 7 more, with ``residual`` 5 more, with ``history_obs`` four times the rest more, float32)``; world frame. The bounds are physical
    (1 m, 5 m/s, 100 N) and observations are clipped to them.

    | index | observation | unit |
    |---|---|---|
    | 0-2 | vector from the tip (EE) to the target | mm |
    | 3-5 | tip linear velocity | mm/s |
    | 6-9 | lengths of the 4 cables (+x, -x, +y, -y) over the active segment | mm |
    | 10 | previous axial (insertion) action | action units |
    | 11 | contact indicator, force-aware only (``force_obs=True``) | 0 or 1 |
    | 12-14 | resultant contact force on the endoscope / ``force_ref_n`` (1 N), force-aware only | - |
    | +0 | insertion depth, ``scope_obs=True`` only (after the blocks above) | mm |
    | +1-3 | tip position from the paper frame's origin (15 mm outside the cardia), ``scope_obs`` only | mm |
    | +4-6 | tip axis, ``scope_obs`` only | unit vector |
    | +0 | share of the trial left, ``1 - step / max_steps``, ``time_obs=True`` only (after the blocks above) | - |
    | +0-1 | sine and cosine of the breathing cycle's phase (the load is +f0 while the sine is positive), ``phase_obs=True`` only (after the blocks above) | - |
    | +0-3 | the previous step's cable actions (as commanded), ``step_obs=True`` only (after the blocks above) | action units |
    | +4-6 | the tip's displacement over the previous step, ``step_obs`` only | mm |
    | +0-4 | the lumen wall's distance from the tip camera's lens (4 mm behind the tip face) along the tip axis and four rays tilted 30 degrees towards +x, -x, +y, -y (100 where no wall is nearer), ``depth_obs=True`` only (after the blocks above) | mm |
    | +0-2 | the lumen surface's normal at the target, into the lumen, ``normal_obs=True`` only (after the blocks above) | unit vector |
    | +0 | the target's free-space distance in the stomach's map, ``plan_obs=True`` only (after the blocks above) | mm |
    | +1-6 | the map's plan for the target: 1 if it needs the wall; the recorded demonstrator's bending while inserting (2), its quarter turn at depth (2) and the share of the trial before the turn (``mjendo.targets.plan_vector``; 0 for free targets), ``plan_obs`` only | - |
    | +0-4 | the DLS baseline's action for this state, which the next action corrects, ``residual=True`` only (after the blocks above) | action units |
    | +0-4n | the last four observations' entries above (n of them), newest first, ``history_obs=True`` only (last of all) | theirs |

    ## Rewards (paper)

    | term | value |
    |---|---|
    | distance | ``-||P_EE - P_target||`` in mm, every step (times ``distance_weight``, 1 by default) |
    | success | ``+1e4`` when the distance is below 3 mm (episode terminates) |
    | exit | ``-1e4`` when the tip leaves the stomach through the cardia, x_EE < 15 mm (terminates) |
    | force | ``-force_penalty * |F|`` (N), 0 by default (optional safety term) |

    Episodes are truncated after ``max_steps`` (128 for training, 80 for the
    paper's evaluation) and when the physics becomes unstable
    (``info["instability"]`` says why).

    ## Arguments

    | argument | default | meaning |
    |---|---|---|
    | ``env`` | set by the id | FE, SE, DE, UE1, UE2 |
    | ``force_obs`` | True | include contact indicator and force (policies C, E) |
    | ``force_off`` | False | the force sensor reads nothing: contact and force observed as 0, the physics unchanged (an ablation: ``python -m mjendo.evaluation --force-off``) |
    | ``scope_obs`` | False | include insertion depth and tip pose (not the paper's; train/policies.yaml variants) |
    | ``time_obs`` | False | include the share of the trial left; reaching ``max_steps`` then terminates instead of truncating (not the paper's) |
    | ``phase_obs`` | False | include the breathing cycle's phase, as a respiratory belt or the ventilator gives it (not the paper's) |
    | ``step_obs`` | False | include what the previous step did: its cable actions and the tip's displacement (not the paper's) |
    | ``depth_obs`` | False | include how far the wall is along five rays from the tip, as the tip camera's depth map gives it (not the paper's) |
    | ``normal_obs`` | False | include which way the wall faces at the target, as the tip camera's picture of it shows (not the paper's) |
    | ``plan_obs`` | False | include the stomach map's plan for the target: its free-space distance and the scripted way to it, as planning on a pre-operative CT would give (not the paper's) |
    | ``residual`` | False | the action corrects the DLS baseline's (``mjendo.baseline``): applied is the baseline's action plus twice the policy's, clipped to [-0.4, 0.4]; the baseline's action is observed (residual policy learning; not the paper's) |
    | ``task_space`` | False | the action is a tip displacement (3 values) that the DLS controller turns into cable and insertion commands (operational-space control; not the paper's) |
    | ``history_obs`` | False | include the last four observations, a frame stack (not the paper's) |
    | ``fidelity`` | "fast" | "fast" (reduced-order stomach), "fast-compliant" (its contact calibrated to the FEM wall's tip paths), "fast-coarse" (on one trilinear cell: faster) or "full" (per-vertex FEM) |
    | ``target_list`` | the env's | "A" (training), "B" (held out), "F" (free-space targets: FE's own), or joined: "A+F" (each list drawn equally often) |
    | ``version`` | set by the id | task version (below) |
    | ``max_steps`` | 128 | truncation limit |
    | ``force_penalty`` | 0.0 | weight of the optional force penalty per newton |
    | ``distance_weight`` | 1.0 | weight of the distance term (the paper's: 1; not the paper's below it: train/policies.yaml variants) |
    | ``success_mm`` | 3.0 | distance at which an episode succeeds (the paper's: 3; a training margin below it: train/policies.yaml variants; trials always use 3) |
    | ``randomize_phase`` | True | start each episode at a random phase of the periodic load (False: phase 0) |
    | ``anatomy`` | None | the stomach: None built-in; a seed (generated, ``anatomy.generate``); a set: "train", "val", "test" (``config.ANATOMY_SETS``) or seeds as "110-119" (one drawn per episode; ``reset(options={"anatomy_index": k})`` picks one); a folder you built |
    | ``randomization`` | None | per-episode tissue stiffness and damping, load amplitude, period and direction, friction and sensor noise, and on request the scope-wall contact impedance (``wall_compliance``), actuation error (``actuation_noise``) and the target's give under the scope (``target_give_mm_per_n``): True for the ranges of ``config.Randomization`` (sourced there), or a dict of its fields (a range set to None is not drawn) |
    | ``render_mode`` | None | "rgb_array" |
    | ``camera`` | "external" | "external", "tip_camera" or "both" (side by side) |
    | ``width``, ``height`` | 480, 360 | frame size in pixels (16-4096) |
    | ``**task`` | | any other TaskConfig field: ``cable_mm_per_unit``, ``insertion_mm_per_unit``, ``control_period_s``, ``force_ref_n``, ``timestep_s`` (the physics step), ``contact_time_constant_s`` (the contacts' and anchors' softness) |

    ``info`` each step: distance_mm, is_success, contact, force_N (3-vector),
    peak_force_N, target_index, anatomy (the stomach), exited, step and the reward terms.
    ``reset``'s info: target_index, distance_mm, anatomy and, with ``randomization``, the episode's draw.

    ## Version history

    * v2 (ids ``mjendo/<env>-10ms-v2``, named apart so ``mjendo/DE`` stays v1): v1 at the full FEM stomach's 10 ms physics step in every stomach (10 physics steps per control
      step; load gains rescaled to v1's target motion), and its own reachability map measured there
      (``python -m mjendo.targets map --version 2``, a wider demonstrator family): at 20 ms MuJoCo holds
      contacts and anchors to a 0.04 s time constant, a softer wall than configured, and at 10 ms known ways
      reach only 28 of v1's 42 contact-aided targets of list A from every start.
    * v1: the contact-aided problem. The insertion tube hangs in a compliant pivot at the cardia
      (the hiatus) instead of a rigid straight slide; the patient lies in the left lateral decubitus
      position (gravity towards the greater curvature); control at 10 Hz with insertion up to
      25 mm/s and cable stroke up to 4 mm/s, so an 80-step trial lasts 8 s (two breathing cycles);
      fast stomach at 20 ms, bending hinges with armature and damping that keep it free of numerical
      events; targets are points on lumen triangles from the reachability map
      (``python -m mjendo.targets map``): lists A and B mostly contact-aided, FE has its own list F.
    * v0: first release: rigid slide, upright gravity, 30 ms control period, 133 mm/s insertion,
      lumen-vertex targets within 20 mm of the free-space workspace.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 40}
    MAX_FRAME_PIXELS = 4096  # MuJoCo's offscreen buffer is enlarged to the frame; beyond this GPUs refuse

    # Task defaults come from TaskConfig (one place); the rendering arguments are the env's own.
    def __init__(self, env: str = TaskConfig.env, force_obs: bool = TaskConfig.force_obs,
                 fidelity: str = TaskConfig.fidelity, target_list: str | None = TaskConfig.target_list,
                 max_steps: int = TaskConfig.max_steps, force_penalty: float = TaskConfig.force_penalty,
                 render_mode: str | None = None, camera: str = "external", width: int = 480,
                 height: int = 360, randomize_phase: bool = TaskConfig.randomize_phase, **task):
        if render_mode not in (None, "rgb_array"):
            raise ConfigError(f"unknown render_mode {render_mode!r}; valid: None, 'rgb_array'")
        if camera not in (*CAMERAS, "both"):
            raise ConfigError(f"unknown camera {camera!r}; valid: {', '.join((*CAMERAS, 'both'))}")
        for name, v in (("width", width), ("height", height)):
            if isinstance(v, bool) or not isinstance(v, int | np.integer) or not 16 <= v <= self.MAX_FRAME_PIXELS:
                raise ConfigError(f"{name} must be a whole number of pixels in [16, {self.MAX_FRAME_PIXELS}], "
                                  f"not {v!r}")
        cfg = task_config(env=env, fidelity=fidelity, force_obs=force_obs, target_list=target_list,
                          max_steps=max_steps, force_penalty=force_penalty, randomize_phase=randomize_phase, **task)
        # One task per stomach the episodes are drawn from (a set of anatomies: several), each built on first use.
        self._members = anatomy.members(cfg.anatomy)
        self._cfg = cfg
        self._tasks: dict[int, NavigationTask] = {}
        self._member_weights: list[np.ndarray] | None = None  # set_target_weights across a set
        self._member_p: np.ndarray | None = None
        self.task = self._task(0)
        self.render_mode = render_mode
        self.camera = camera
        self.width, self.height = int(width), int(height)
        self._renderer = None
        self.metadata = {**self.metadata, "render_fps": int(round(1.0 / self.task.control_dt))}
        self.action_space = gym.spaces.Box(-PAPER_ACTION_LIMIT, PAPER_ACTION_LIMIT, (action_size(cfg),), np.float32)
        self.observation_space = gym.spaces.Box(self.task.obs_low, self.task.obs_high, dtype=np.float32)

    def anatomy_task(self, k: int) -> NavigationTask:
        """The task in the k-th stomach the episodes are drawn from (built on first use)."""
        return self._task(k)

    def _task(self, k: int) -> NavigationTask:
        if k not in self._tasks:
            self._tasks[k] = NavigationTask(replace(self._cfg, anatomy=self._members[k]))
        return self._tasks[k]

    @property
    def anatomies(self) -> list:
        """The stomachs episodes are drawn from (None: the built-in one)."""
        return list(self._members)

    def set_target_weights(self, weights) -> None:
        """Training's hook (``VecEnv.env_method``) for how often each target is drawn: see mjendo.sampling.

        Across a set of stomachs, one array per stomach (``anatomies`` order): a stomach is drawn in proportion
        to its weights' sum, then a target of its list by them; None restores the uniform draws.
        """
        if len(self._members) == 1:
            self.task.set_target_weights(weights)
            return
        if weights is None:
            self._member_weights = None
            for task in self._tasks.values():
                task.set_target_weights(None)
            return
        w = [np.asarray(x, float) for x in weights]
        sums = np.array([x.sum() for x in w])
        if len(w) != len(self._members) or not np.all(np.isfinite(sums)) or sums.min() < 0 or sums.sum() <= 0:
            raise ValueError(f"target weights across a set: one array per stomach ({len(self._members)}), finite, "
                             "not all 0")
        self._member_weights, self._member_p = w, sums / sums.sum()

    def _check_options(self, options: dict) -> None:
        """A misspelt or misplaced reset option is refused, not ignored: the episode would silently be another."""
        unknown = sorted(set(options) - {"target_index", "anatomy_index"})
        if unknown:
            raise ConfigError(f"unknown reset option(s) {', '.join(map(str, unknown))}; valid: target_index (a "
                              "target of env.unwrapped.task.targets), anatomy_index (with a set of stomachs)")
        for key, n in (("target_index", None), ("anatomy_index", len(self._members))):
            if key in options and (isinstance(options[key], bool) or not isinstance(options[key], (int, np.integer))):
                raise ConfigError(f"reset option {key} must be a whole number, not {options[key]!r}")
            if key == "anatomy_index" and key in options and not 0 <= options[key] < n:
                raise ConfigError(f"anatomy_index {options[key]} is not one of this environment's {n} stomach(s) "
                                  "(0 to {}); a set of stomachs is anatomy='train', 'val' or 'test'".format(n - 1))

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        options = options or {}
        self._check_options(options)
        if len(self._members) > 1:
            if "anatomy_index" in options:
                k = int(options["anatomy_index"])
            elif self._member_weights is None:
                k = int(self.np_random.integers(len(self._members)))
            else:
                k = int(self.np_random.choice(len(self._members), p=self._member_p))
            task = self._task(k)
            if self._member_weights is not None:
                task.set_target_weights(self._member_weights[k])
            if task is not self.task and self._renderer is not None:
                self.close()  # the renderer belongs to the previous stomach's model
            self.task = task
        obs = self.task.reset(self.np_random)
        if "target_index" in options:
            obs = self.task.set_target(int(options["target_index"]))
        info = {"target_index": self.task.target, "distance_mm": self.task.distance_mm(),
                "anatomy": self.task.cfg.anatomy}
        if self.task.episode_params is not None:
            info["randomization"] = self.task.episode_params
        return obs, info

    def step(self, action):
        r = self.task.step(action)
        return r.obs, r.reward, r.terminated, r.truncated, r.info

    # -------------------------------------------------------------- render
    def render(self):
        if self.render_mode != "rgb_array":
            return None
        if self._renderer is None:
            self._renderer = mujoco.Renderer(self.task.sim.model, self.height, self.width)
            if not _RENDERING:
                atexit.unregister(_close_renderers)
                atexit.register(_close_renderers)
            _RENDERING.add(self)
        cams = CAMERAS if self.camera == "both" else (self.camera,)
        frames = []
        for cam in cams:
            self._renderer.update_scene(self.task.sim.data, camera=cam)
            frames.append(self._renderer.render())
        return np.concatenate(frames, axis=1)

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __getstate__(self):
        # The renderer holds OpenGL pointers that cannot be copied or pickled; render() makes a new one.
        state = self.__dict__.copy()
        state["_renderer"] = None
        return state

