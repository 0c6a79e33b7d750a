"""Guided starts from the reachability map's demonstrators (``TrainConfig.guide_steps``), for training only.

Every contact-aided target of a map has, for each of the four DE load phases, a recorded open-loop
demonstrator that reaches it within one trial (:data:`mjendo.targets.DEMOS`: bend while inserting at
full speed, optionally turn the bending at depth). With guided starts an episode aimed at such a target
begins with the first h steps of its demonstrator, h drawn from 0 to a maximum that training lowers to
0, and the policy acts from there (jump-start RL, Uchendu et al. 2023; the reverse curriculum from a
demonstration of Salimans and Chen 2018). The policy learns from states on fast ways to the targets it
reaches late, and nothing pulls its actions towards the open-loop script's: its closed-loop corrections
stay its own (cloning the script's actions beside PPO undid them: docs/training.md).
"""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym

from mjendo import targets
from mjendo.config import PAPER_SUCCESS_MM


def demo_run(env: str, start: int, n_starts: int) -> int:
    """Index into a point's recorded demonstrators (the map's SE run, then its DE phases) for an episode in
    ``env`` that began from start state ``start`` of ``n_starts``: the nearest recorded phase."""
    if env == "SE":
        return 0
    return 1 + int(round(start * targets.PHASES / n_starts)) % targets.PHASES


class GuidedStarts(gym.Wrapper):
    """Begins each episode aimed at a contact-aided target with up to ``max_guide`` steps of its demonstrator
    (drawn uniformly, 0 included); the policy, its Monitor and its rollouts see the episode from there."""

    def __init__(self, env: gym.Env):
        super().__init__(env)
        self.max_guide = 0
        self._demos: dict[Path, dict[int, list[int]]] = {}  # per stomach folder: point id -> recorded demos

    def set_guide_steps(self, n: int) -> None:
        """Training's hook (``VecEnv.env_method``): the most steps the demonstrator may take."""
        self.max_guide = max(0, int(n))

    def _recorded(self, task) -> dict[int, list[int]]:
        folder = Path(task.stomach_dir)
        if folder not in self._demos:
            meta = targets.read_map(targets.map_path(folder, task.cfg.version))
            self._demos[folder] = {p["id"]: p["demos"] for p in meta["points"]
                                   if p["class"] == "contact_aided" and p.get("demos")}
        return self._demos[folder]

    def reset(self, **kw):
        obs, info = self.env.reset(**kw)
        if self.max_guide <= 0:
            return obs, info
        task = self.env.unwrapped.task
        recorded = self._recorded(task).get(task.target)
        if recorded is None:  # a free target: the policy starts it
            return obs, info
        demo = targets.DEMOS[recorded[demo_run(task.cfg.env, task.start_index, len(task.start_states))]]
        for k in range(int(self.np_random.integers(self.max_guide + 1))):
            if task.distance_mm() < 2 * PAPER_SUCCESS_MM:  # leave the arrival to the policy
                break
            obs, _r, terminated, truncated, info = self.env.step(targets.demo_action(demo, k))
            if terminated or truncated:  # left through the cardia, say: start this episode unguided
                return self.env.reset(**{**kw, "seed": None})
        info["guided_steps"] = task.steps
        return obs, info
