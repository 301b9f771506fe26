"""A structured control net for PPO (Srouji, Zhang and Salakhutdinov, "Structured Control Nets
for Deep Reinforcement Learning", ICML 2018): the action's mean is a linear map of the
(normalised) observation plus the MLP's output, ``W_l x + W_n mlp(x) + b``, both learned from
scratch (nothing of a controller is put in).

Tracking is mostly a linear law of what the policy sees (the next reference displacement and the
measured error), with configuration-, load- and temperature-dependent corrections on top: the
linear path learns the first at once and the MLP the rest, where a bare MLP spends its capacity
and its training steps approximating a linear map to a few micrometres.

In stable-baselines3 terms it is an :class:`~stable_baselines3.common.policies.ActorCriticPolicy`
whose actor latent is ``[x, mlp(x)]``: ``action_net`` (and gSDE's noise) read both. The critic is
the usual MLP. Set by ``policy_kwargs.structured = true`` (PPO only); this module imports torch,
so :mod:`agents.policy` imports it only when a structured network is built."""

from __future__ import annotations

from typing import Any

import torch as th
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import MlpExtractor


class StructuredExtractor(MlpExtractor):
    """:class:`MlpExtractor` whose actor latent is the features themselves beside the MLP's."""

    def __init__(self, feature_dim: int, net_arch: Any, activation_fn: Any, device: Any) -> None:
        super().__init__(feature_dim, net_arch=net_arch, activation_fn=activation_fn, device=device)
        self.latent_dim_pi = feature_dim + self.latent_dim_pi

    def forward(self, features: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        return self.forward_actor(features), self.forward_critic(features)

    def forward_actor(self, features: th.Tensor) -> th.Tensor:
        return th.cat([features, self.policy_net(features)], dim=-1)


class StructuredActorCriticPolicy(ActorCriticPolicy):
    """PPO's actor-critic with a linear path from the observation to the action's mean."""

    def _build_mlp_extractor(self) -> None:
        self.mlp_extractor = StructuredExtractor(
            self.features_dim,
            net_arch=self.net_arch,
            activation_fn=self.activation_fn,
            device=self.device,
        )
