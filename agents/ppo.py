"""Proximal Policy Optimisation with the options PHC's recipe relies on.

The loop, the env, the policy, rollouts and checkpoints are the on-policy base's
(`on_policy.OnPolicyAlgorithm`); PPO is its settings (`PPOConfig`) and its update: `n_epochs` of
clipped-surrogate minibatch steps over each rollout. Everything PHC tunes is a setting: GAE,
value normalisation (the policy's), the clipped surrogate and value clip, the bounds loss on the
action mean, gradient clipping, minibatches and epochs, a target-KL stop, a critic-only warm-up
for warm starts; the actor-critic's own
(fixed or learned action std, observation normalisation, separate actor and critic MLPs) are the
policy's arguments (`networks.ActorCritic`).

Subclasses (AMP) extend it through the base's hooks and `_update_extra` (after the policy's update).
"""
from __future__ import annotations

import dataclasses

import numpy as np
import torch

from .networks import ActionEval
from .on_policy import OnPolicyAlgorithm, OnPolicyConfig
from .optim import flush_subnormals_
from .rollout import RolloutBuffer


@dataclasses.dataclass
class PPOConfig(OnPolicyConfig):
    """PPO's hyperparameters: keyword arguments of `PPO(...)`, stored in checkpoints (the shared
    on-policy ones first)."""

    clip_range: float = 0.2
    """PPO ratio clip"""
    clip_range_vf: float | None = None
    """optional clip of the value update around the old value, in the critic's (normalised) units"""
    ent_coef: float = 0.0
    """entropy bonus weight (PHC: 0)"""
    vf_coef: float = 1.0
    """value-loss weight (PHC: 5)"""
    bounds_loss_coef: float = 0.0
    """penalty on action means beyond +-bounds_loss_limit (PHC: 10)"""
    bounds_loss_limit: float = 1.1
    """where that penalty starts (PHC: 1.1; PULSE's latent tasks: 1)"""
    target_kl: float | None = None
    """stop an update's epochs early once the approximate KL exceeds 1.5x this"""
    critic_warmup: int = 0
    """env steps at the start of training in which only the critic learns (the policy's loss is
    left out of the update): a warm-started policy facing a new reward is not pushed about by
    advantages from a critic that has not learnt that reward yet"""
    normalize_advantage: bool = True
    """per-minibatch advantage standardisation"""


class PPO(OnPolicyAlgorithm):
    """PPO for Box action spaces on any Gymnasium env, single or vector. Arguments: those of
    `OnPolicyAlgorithm` (env, policy, policy_kwargs, device ...), and the fields of `PPOConfig`
    as keyword arguments."""

    config_class = PPOConfig
    _critic_only = False  # this update leaves the policy's loss out (`critic_warmup`)

    def _update(self, buf: RolloutBuffer) -> None:
        cfg, pol = self.config, self.policy
        data = buf.transitions()
        pol.update_value_stats(data["returns"])
        stats: dict[str, list[float]] = {k: [] for k in ("policy_loss", "value_loss", "entropy", "bounds_loss",
                                                         "approx_kl", "clip_fraction", "grad_norm")}
        stop = False
        self._critic_only = self.num_timesteps <= cfg.critic_warmup
        if cfg.critic_warmup:
            self.logger.record("train/critic_only", float(self._critic_only))
        sync = self._gradient_sync(pol, self.optimizer)  # averages gradients across a job's ranks
        for _ in range(cfg.n_epochs):
            for mb in self._minibatches(data, cfg.batch_size):
                terms = sync.loss(lambda: self._loss(mb))
                loss, policy_loss, value_loss, entropy, bounds_loss, ratio, log_ratio = terms
                self.optimizer.zero_grad(set_to_none=True)
                sync.backward(loss)
                grad_norm = torch.nn.utils.clip_grad_norm_(pol.parameters(), cfg.max_grad_norm)
                self.optimizer.step()

                with torch.no_grad():
                    approx_kl = ((ratio - 1) - log_ratio).mean().item()
                    clip_fraction = ((ratio - 1).abs() > cfg.clip_range).float().mean().item()
                for k, v in (("policy_loss", policy_loss), ("value_loss", value_loss), ("entropy", entropy),
                             ("bounds_loss", bounds_loss), ("grad_norm", grad_norm)):
                    stats[k].append(float(v.detach()))
                stats["approx_kl"].append(approx_kl)
                stats["clip_fraction"].append(clip_fraction)
                # Every rank of a job stops on the same step: on the KL of all their data.
                if cfg.target_kl is not None and self.data_parallel.mean(approx_kl) > 1.5 * cfg.target_kl:
                    stop = True
                    break
            if stop:
                break
        for k, v in stats.items():
            if v:
                self.logger.record(f"train/{k}", float(np.mean(v)))
        ret, val = data["returns"], data["values"]
        var = ret.var() if len(ret) > 1 else torch.tensor(0.0)
        self.logger.record("train/explained_variance", float(1 - (ret - val).var() / var) if var > 0 else float("nan"))
        std = pol.action_std()
        if std is not None:
            self.logger.record("train/std", float(std.mean()))
        flush_subnormals_(self.optimizer)
        self._update_extra(buf)

    def _loss(self, mb: dict[str, torch.Tensor]) -> tuple[torch.Tensor, ...]:
        """(loss, policy loss, value loss, entropy, bounds loss, ratio, log ratio) of a minibatch."""
        return self._ppo_loss(mb, self.policy.evaluate_actions(mb["obs"], mb["actions"]))

    def _ppo_loss(self, mb: dict[str, torch.Tensor], ev: ActionEval) -> tuple[torch.Tensor, ...]:
        """`_loss`'s terms from the policy's evaluation of the minibatch, for subclasses that add
        terms of their own to the same forward pass."""
        cfg, pol = self.config, self.policy
        log_ratio = ev.log_prob - mb["log_probs"]
        ratio = log_ratio.exp()
        adv = mb["advantages"]
        if cfg.normalize_advantage and len(adv) > 1:
            adv = (adv - adv.mean()) / (adv.std() + 1e-8)
        policy_loss = torch.max(-adv * ratio, -adv * ratio.clamp(1 - cfg.clip_range, 1 + cfg.clip_range)).mean()

        # The critic learns in its own units (normalised returns when normalize_value).
        v_pred = ev.value
        v_target, v_old = pol.value_targets(mb["returns"]), pol.value_targets(mb["values"])
        value_loss = (v_pred - v_target).square()
        if cfg.clip_range_vf is not None:
            v_clip = v_old + (v_pred - v_old).clamp(-cfg.clip_range_vf, cfg.clip_range_vf)
            value_loss = torch.max(value_loss, (v_clip - v_target).square())
        value_loss = 0.5 * value_loss.mean()

        entropy = ev.entropy.mean()
        mu = ev.mean
        bound = cfg.bounds_loss_limit
        bounds_loss = ((mu - bound).clamp(min=0).square() + (mu + bound).clamp(max=0).square()).sum(-1).mean()
        if self._critic_only:
            loss = cfg.vf_coef * value_loss
        else:
            loss = policy_loss + cfg.vf_coef * value_loss - cfg.ent_coef * entropy + cfg.bounds_loss_coef * bounds_loss
        return loss, policy_loss, value_loss, entropy, bounds_loss, ratio, log_ratio

    def _update_extra(self, buf: RolloutBuffer) -> None:
        """Anything else to train on the rollout, after the policy's update."""


__all__ = ["PPO", "PPOConfig"]
