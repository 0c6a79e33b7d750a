"""A classic (not learned) controller: damped least squares on a constant-curvature model.

It reads the cable lengths (bending state) and the pose of the active
segment's base, models the active segment as a constant-curvature arc
(the standard kinematic model of tendon-driven continuum robots), and moves
the tip towards the target by damped least squares on that model's Jacobian.
It ignores contact entirely: the row it fills in the evaluation tables shows
what free-space kinematics achieves without the CAN strategy.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import mujoco
import numpy as np

from mjendo.config import PAPER_ACTION_LIMIT, Endoscope
from mjendo.endoscope import LINK_PREFIX
from mjendo.units import from_mm

if TYPE_CHECKING:  # the task runs this controller under its own actions (TaskConfig.residual, task_space)
    from mjendo.task import NavigationTask


def arc_tip(theta: np.ndarray, length: float) -> np.ndarray:
    """Tip of a constant-curvature arc bent by (theta_x, theta_y), in its base frame."""
    angle = float(np.hypot(*theta))
    if angle < 1e-6:
        return np.array([theta[0] * length / 2, theta[1] * length / 2, length])
    d = theta / angle
    r = length / angle
    return np.array([d[0] * r * (1 - np.cos(angle)), d[1] * r * (1 - np.cos(angle)), r * np.sin(angle)])


class DLSController:
    """``act(obs, task)`` returns an action in [-0.4, 0.4]^5; contact-blind."""

    name = "DLS baseline"

    def __init__(self, task: NavigationTask, damping_m: float = 0.01, cfg: Endoscope | None = None):
        self.cfg = cfg or Endoscope()
        c = self.cfg
        self.length = from_mm(c.active_length_mm)
        self.r = from_mm(c.cable_offset_mm)
        n = c.n_active_links
        k = c.active_EI_Nm2 / (self.length / n)
        # Quasi-static bend per metre of differential cable pull: the cable
        # servo (kp) in series with n joints of stiffness k at lever arm r.
        self.rad_per_m = n * self.r * c.cable_kp_n_per_m / (k + n * self.r**2 * c.cable_kp_n_per_m)
        self.damping = damping_m
        m = task.sim.model
        self.base_body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"{LINK_PREFIX}{c.n_passive_links}")
        self.rest = None

    def reset(self, task: NavigationTask) -> None:
        self.rest = task.sim.cable_lengths()

    def bend(self, task: NavigationTask) -> np.ndarray:
        """Bending angles (theta_x, theta_y) estimated from the cable lengths."""
        if self.rest is None:
            self.reset(task)
        dl = task.sim.cable_lengths() - self.rest  # +x, -x, +y, -y
        return np.array([dl[1] - dl[0], dl[3] - dl[2]]) / (2 * self.r)

    def act(self, obs, task: NavigationTask) -> np.ndarray:
        return self.toward(task, task.target_pos() - task.sim.tip_pos())

    def toward(self, task: NavigationTask, error: np.ndarray) -> np.ndarray:
        """The action that moves the tip by ``error`` (m, world frame) on the model, clipped to the box: the
        baseline aims it at the target, a task-space policy (TaskConfig.task_space) wherever it chooses."""
        d = task.sim.data
        pos, rot = d.xpos[self.base_body], d.xmat[self.base_body].reshape(3, 3)
        theta = self.bend(task)

        def model(q):
            return pos + rot @ arc_tip(q[:2], self.length) + q[2] * rot[:, 2]

        q0 = np.array([theta[0], theta[1], 0.0])
        jac = np.zeros((3, 3))
        for i, h in enumerate((1e-4, 1e-4, 1e-5)):
            dq = np.zeros(3)
            dq[i] = h
            jac[:, i] = (model(q0 + dq) - model(q0 - dq)) / (2 * h)
        step = jac.T @ np.linalg.solve(jac @ jac.T + self.damping**2 * np.eye(3), error)
        goal = theta + step[:2]
        pulls = np.array([goal[0], -goal[0], goal[1], -goal[1]]) / self.rad_per_m
        action = np.empty(5)
        action[:4] = (pulls - task.pulls) / task.cable_step
        action[4] = step[2] / task.insertion_step
        return np.clip(action, -PAPER_ACTION_LIMIT, PAPER_ACTION_LIMIT)
