"""Gymnasium ids: ``mjendo/<env>-v<version>`` for every environment and task version, and the paper's id.

``-v1`` is the current task (compliant cardia pivot, left lateral decubitus, literature time scales,
targets on the lumen surface that need the wall), so ``mjendo/DE`` resolves to it; ``-v0`` is the first
release's task, kept so its tables can be reproduced; version 2, an alternative at the FEM stomach's 10 ms
step, is ``mjendo/<env>-10ms-v2`` (``TaskVersion.gym_tag``). The version history is in
:class:`mjendo.envs.EndoscopeEnv`.
"""

import gymnasium as gym

from mjendo.config import CONDITIONS, CURRENT_VERSION, VERSIONS, task_version

PAPER_ID = "endogym-v0"  # paper: the Gymnasium id of its DE environment (the current task here)


def gym_id(env: str, version: int = CURRENT_VERSION) -> str:
    tag = task_version(version).gym_tag
    return f"mjendo/{env}-{tag}-v{version}" if tag else f"mjendo/{env}-v{version}"


def register_all() -> None:
    """Register one id per environment and task version, plus the paper's ``endogym-v0`` (current DE)."""
    for version in VERSIONS:
        for name in CONDITIONS:
            if gym_id(name, version) not in gym.registry:
                gym.register(id=gym_id(name, version), entry_point="mjendo.envs:EndoscopeEnv",
                             kwargs={"env": name, "version": version})
    if PAPER_ID not in gym.registry:
        gym.register(id=PAPER_ID, entry_point="mjendo.envs:EndoscopeEnv", kwargs={"env": "DE"})
