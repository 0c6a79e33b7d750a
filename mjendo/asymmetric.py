"""An asymmetric actor-critic: the value function sees inputs the policy does not.

The policy must act on what a deployed scope measures (the paper's observation), but its value function is
only used in training, where the simulator knows more: the insertion depth and tip pose, the time left in the
trial and the breathing phase. A critic given that state estimates returns, and so advantages, better in a
partially observed task (Pinto et al. 2018, "Asymmetric Actor Critic for Image-Based Robot Learning").
The critic-only blocks come last in the observation; the actor's network receives them as zeros, so its
actions do not depend on them (tested) and a trained policy acts the same whatever they hold.
"""

from __future__ import annotations

from typing import Any

import torch
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import MlpExtractor

from mjendo.config import ConfigError, TaskConfig
from mjendo.task import OBS_OPTIONS, obs_options, obs_size

# Observation options whose blocks may be given to the critic alone (the force is the policy's own input).
CRITIC_ONLY_OPTIONS = ("scope_obs", "time_obs", "phase_obs")


def actor_inputs(task: TaskConfig, critic_only: list[str]) -> int:
    """How many leading observation entries the policy sees when ``critic_only`` blocks go to the critic alone."""
    bad = [k for k in critic_only if k not in CRITIC_ONLY_OPTIONS]
    if bad:
        raise ConfigError(f"critic_only: {bad} cannot be critic-only inputs; valid: {', '.join(CRITIC_ONLY_OPTIONS)}")
    have = obs_options(task)
    off = [k for k in critic_only if not have[k]]
    if off:
        raise ConfigError(f"critic_only names {off}, which the task does not observe: set them true in the task "
                          "block too (e.g. task: {scope_obs: true})")
    actor = {k: have[k] and k not in critic_only for k in OBS_OPTIONS}
    if critic_only and any(actor[k] for k in OBS_OPTIONS[OBS_OPTIONS.index(min(critic_only, key=OBS_OPTIONS.index)):]):
        raise ConfigError(f"critic_only {critic_only}: the critic-only blocks must come after every block the policy "
                          f"sees (observation order {', '.join(OBS_OPTIONS)})")
    return obs_size(**actor)


class ActorMaskedExtractor(MlpExtractor):
    """SB3's two MLPs, the policy's fed zeros in place of every input from ``actor_inputs`` on."""

    def __init__(self, *args, actor_inputs: int, **kwargs):
        super().__init__(*args, **kwargs)
        self.actor_inputs = actor_inputs

    def forward_actor(self, features: torch.Tensor) -> torch.Tensor:
        seen = features[..., :self.actor_inputs]
        hidden = torch.zeros_like(features[..., self.actor_inputs:])
        return super().forward_actor(torch.cat((seen, hidden), -1))


class AsymmetricPolicy(ActorCriticPolicy):
    """SB3's ActorCriticPolicy whose actor sees only the first ``actor_inputs`` observation entries.

    The networks keep SB3's layout and parameter names, so a policy trained without critic-only inputs widens
    into this one (:mod:`mjendo.widen`) and PPO saves and loads it as any other.
    """

    def __init__(self, *args, actor_inputs: int, **kwargs):
        self.actor_inputs = actor_inputs  # read by _build_mlp_extractor, which the base constructor calls
        super().__init__(*args, **kwargs)

    def _build_mlp_extractor(self) -> None:
        self.mlp_extractor = ActorMaskedExtractor(self.features_dim, net_arch=self.net_arch,
                                                  activation_fn=self.activation_fn, device=self.device,
                                                  actor_inputs=self.actor_inputs)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        return {**super()._get_constructor_parameters(), "actor_inputs": self.actor_inputs}
