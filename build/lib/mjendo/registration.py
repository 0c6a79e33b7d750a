"""Gymnasium ids for mjendo, registered on ``import mjendo`` without importing Gymnasium eagerly.

Gymnasium expects ``import mjendo`` to register the ids. Registering needs
Gymnasium itself, which a user of ``mjendo.units`` or ``mjendo.anatomy``
does not need: so the ids are registered at once when Gymnasium is already
loaded, and otherwise the moment it is (an import hook that stays out of the
way of every other import). Either way ``gym.make("mjendo/DE-v0")`` works
after ``import mjendo``.
"""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import sys

from mjendo.config import CONDITIONS

PAPER_ID = "endogym-v0"  # paper: the Gymnasium id of its DE environment


def gym_id(env: str) -> str:
    return f"mjendo/{env}-v0"


def register_all() -> None:
    """Register one Gymnasium id per environment, plus the paper's ``endogym-v0`` (DE)."""
    import gymnasium as gym

    for name in CONDITIONS:
        if gym_id(name) not in gym.registry:
            gym.register(id=gym_id(name), entry_point="mjendo.envs:EndoscopeEnv", kwargs={"env": name})
    if PAPER_ID not in gym.registry:
        gym.register(id=PAPER_ID, entry_point="mjendo.envs:EndoscopeEnv", kwargs={"env": "DE"})


class _AfterGymnasium(importlib.abc.MetaPathFinder):
    """Finds nothing itself; wraps Gymnasium's own loader so registration runs once it has loaded."""

    def find_spec(self, fullname, path=None, target=None):
        if fullname != "gymnasium":
            return None
        sys.meta_path.remove(self)
        spec = importlib.machinery.PathFinder.find_spec(fullname, path)
        if spec is None or spec.loader is None:
            return spec
        exec_module = spec.loader.exec_module

        def exec_then_register(module):
            exec_module(module)
            register_all()

        spec.loader.exec_module = exec_then_register
        return spec


def register_when_gymnasium_loads() -> None:
    if "gymnasium" in sys.modules:
        register_all()
    elif not any(isinstance(f, _AfterGymnasium) for f in sys.meta_path):
        sys.meta_path.insert(0, _AfterGymnasium())
