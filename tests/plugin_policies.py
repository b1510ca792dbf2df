"""Plug-ins the tests load by import path (`plugin_policies:PrimitiveMixer`), as a user's package
would provide them: a policy with its own action size and an observation-dependent map to the
env's actions, and a second algorithm on the on-policy base."""
from __future__ import annotations

import numpy as np
import torch
from torch import nn
from torch.distributions import Normal

from agents import OnPolicyAlgorithm, Policy, RolloutHooks
from agents.networks import mlp
from agents.normalizer import RunningNorm


class PrimitiveMixer(Policy):
    """A composer in miniature: its actions are one logit per primitive; the env gets the
    softmax-weighted sum of the frozen primitives' actions on the same observation."""

    def __init__(self, obs_dim, action_space, *, primitives, hidden=(32,), log_std_init=-1.0):
        super().__init__(obs_dim, action_space, act_dim=len(primitives))
        self.primitives = nn.ModuleList(primitives)  # registered, so their weights are in the state dict
        self.obs_norm = RunningNorm(obs_dim)
        self.actor = mlp(obs_dim, hidden, self.act_dim, "tanh", out_gain=0.01)
        self.critic = mlp(obs_dim, hidden, 1, "tanh")
        self.log_std = nn.Parameter(torch.full((self.act_dim,), float(log_std_init)))

    def normalize(self, obs):
        return self.obs_norm(obs)

    def update_obs_stats(self, obs):
        self.obs_norm.update(obs)

    def forward(self, nobs):
        mu = self.actor(nobs)
        return Normal(mu, self.log_std.exp().expand_as(mu)), self.value(nobs)

    def value(self, nobs):
        return self.critic(nobs).squeeze(-1)

    def env_action(self, action, obs):
        weights = torch.softmax(action, -1)                                                  # (B, k)
        actions = torch.stack([p.env_action(p.act(obs), obs) for p in self.primitives], -1)  # (B, 69, k)
        return (actions * weights[:, None, :]).sum(-1)


class TeacherLabels(RolloutHooks):
    """The teacher's actions on each rollout's raw observations, in one batch at its end."""

    FIELD = "teacher_actions"

    def __init__(self, teacher: Policy):
        self.teacher = teacher

    def on_rollout_start(self, buffer):
        self.labels = buffer.extra(self.FIELD, self.teacher.act_dim)

    def on_rollout_end(self, buffer):
        obs = buffer.obs.reshape(-1, buffer.obs.shape[-1])
        self.labels.copy_(self.teacher.act(obs).reshape(self.labels.shape))


class Distill(OnPolicyAlgorithm):
    """Behaviour cloning of a fixed teacher on the student's own rollouts (DAgger's relabelling):
    the student acts, the teacher labels, the student's action mean regresses on the labels. The
    base does the rest (env, rollouts, logging, checkpoints)."""

    def __init__(self, env, *, teacher: Policy, **kwargs):
        self.teacher = teacher.freeze()
        super().__init__(env, **kwargs)

    def _rollout_hooks(self):
        return TeacherLabels(self.teacher.to(self.device))

    def _update(self, buf):
        labels = buf.extras[TeacherLabels.FIELD]
        data = {"obs": buf.transitions()["obs"], "target": labels.reshape(-1, labels.shape[-1])[buf.valid_mask()]}
        losses, sync = [], self._gradient_sync(self.policy, self.optimizer)  # data-parallel ready
        for _ in range(self.config.n_epochs):
            for mb in self._minibatches(data, self.config.batch_size):
                loss = sync.loss(lambda: (self.policy.action_distribution(mb["obs"]).mean
                                          - mb["target"]).square().mean())
                self.optimizer.zero_grad(set_to_none=True)
                sync.backward(loss)
                torch.nn.utils.clip_grad_norm_(self.policy.parameters(), self.config.max_grad_norm)
                self.optimizer.step()
                losses.append(loss.item())
        self.logger.record("train/bc_loss", float(np.mean(losses)))
