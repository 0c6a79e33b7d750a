"""How training draws its targets: uniformly, from a joined pool of lists, with contact-aided targets phased
in, or prioritised on failures.

Uniform draws leave the few free targets of a list that is two-thirds contact-aided under-trained: the
paper-config E reached 83 % of list A's contact-aided targets in DE but 41 % of its free ones, while the
contact-blind baseline reached 93 % of those (docs/training.md). Prioritised goal sampling, as in
curriculum learning over goals and levels, draws a target more often the less reliably the policy solves
it *within a trial* (PAPER_EVAL_STEPS), so slow successes keep their weight too. Across a set of stomachs
the sampler holds every stomach's list, each stomach drawn as often as the others under uniform draws, and
prioritises (stomach, target) pairs, as prioritised level replay does over generated levels (Jiang et al. 2021).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from mjendo.config import PAPER_EVAL_STEPS, ConfigError

SAMPLINGS = ("uniform", "adaptive")
FLOOR = 0.2  # weight of a target solved every time: a solved target is drawn 1/6 as often as a failed one
MEMORY = 0.2  # EMA rate of a target's solve rate: about its last five episodes


def _key(target):
    """A target's key: its index in one stomach, (stomach seed, index) across a set (JSON keeps pairs as lists)."""
    return tuple(int(x) for x in target) if isinstance(target, (tuple, list)) else int(target)


class TargetSampler:
    """Per-target solve rates of a training run and the draw weights they imply.

    ``targets``: one stomach's listed targets, or across a set (stomach seed, target) pairs grouped by stomach,
    ``sizes`` the length of each stomach's group in the set's order.
    """

    def __init__(self, targets, contact_aided, sampling: str = "uniform", curriculum_steps: int = 0, base=None,
                 sizes: list[int] | None = None):
        if sampling not in SAMPLINGS:
            raise ConfigError(f"target_sampling must be one of {', '.join(SAMPLINGS)}, not {sampling!r}")
        self.targets = [_key(t) for t in targets]
        self.contact_aided = np.asarray(contact_aided, bool)
        self.sampling, self.curriculum_steps = sampling, int(curriculum_steps)
        self.sizes = sizes
        self.solved = np.zeros(len(self.targets))  # EMA of "reached within a trial's steps"
        # relative draw weight before curriculum and adaptation (a joined pool: each list equally often)
        self.base = np.ones(len(self.targets)) if base is None else np.asarray(base, float)
        self._row = {t: i for i, t in enumerate(self.targets)}

    @property
    def active(self) -> bool:
        """Whether the draw differs from the paper's uniform one at some point of the run (across a set each
        stomach's task draws its own joined pool already)."""
        return (self.sampling != "uniform" or self.curriculum_steps > 0
                or bool(self.sizes is None and self.base.size and np.ptp(self.base) > 0))

    def key(self, info: dict):
        """The key of an episode's target from its step info: the stomach too across a set."""
        return info["target_index"] if self.sizes is None else (info["anatomy"], info["target_index"])

    def record(self, target, success: bool, length: int) -> None:
        """One finished training episode: solved means reached within a trial (PAPER_EVAL_STEPS)."""
        i = self._row.get(_key(target))
        if i is not None:
            self.solved[i] += MEMORY * (float(success and length <= PAPER_EVAL_STEPS) - self.solved[i])

    def weights(self, timesteps: int) -> np.ndarray:
        """Relative draw weight of each listed target (list order) at ``timesteps`` of training."""
        w = self.base.copy()
        if self.curriculum_steps:  # contact-aided targets phase in over curriculum_steps
            w *= np.where(self.contact_aided, min(1.0, timesteps / self.curriculum_steps), 1.0)
        if self.sampling == "adaptive":
            w = w * (FLOOR + 1.0 - self.solved)
        return w

    def env_weights(self, timesteps: int):
        """What ``EndoscopeEnv.set_target_weights`` takes: the weights, split by stomach across a set."""
        w = self.weights(timesteps)
        return w if self.sizes is None else np.split(w, np.cumsum(self.sizes)[:-1])

    def save(self, path: Path) -> None:
        path.write_text(json.dumps({"targets": self.targets, "solved": self.solved.tolist()}))

    def load(self, path: Path) -> None:
        """Solve rates of a checkpoint (a resumed run draws as the killed one did); other lists are ignored."""
        if path.exists():
            saved = json.loads(path.read_text())
            if [_key(k) for k in saved.get("targets", [])] == self.targets:
                self.solved = np.array(saved["solved"], float)
