"""PULSE's latent action space on the environment side: the prior and decoder that turn a latent
action a in R^32 into the humanoid's action, D(s_p, mu_prior(s_p) + a).

Why the two networks live here, in the environment package: a latent space is only useful if
any RL library can act in it with nothing but a task and a PULSE checkpoint
(`smpl_envs.wrappers.LatentAction`), and smpl_envs must not import agents (the data path runs
one way: tests/test_imports.py). So the part of PULSE a latent action needs is one module,
`LatentDecoder`, that both packages use: agents.PULSE trains it as part of its policy (the
encoder, which only distillation needs, stays in agents), agents' latent-task policy
(`agents.LatentActorCritic`) maps its actions through it, and `LatentDecoder.from_checkpoint`
reads it out of a PULSE checkpoint file on its own. One decoder, one implementation.

s_p, the proprioception, is the self observation: the first `PROPRIO_DIM` (358) columns of every
task's observation (`features.SELF_OBS_LAYOUT`: root height, body positions, velocities and
rotations in the heading frame; Terrain measures the root height above the ground under the
pelvis, as the flat tasks do above the floor). The prior and the decoder see it normalised with
the distillation run's statistics and clamped to +-obs_clip (5; REFERENCE section 8).

The decoder's actions are absolute PD targets in [-1, 1]^69 (`action_mode="absolute"`), the one
action form every task takes; `settings` records the policy settings of the env it was distilled
in (substeps, action_mode), which an env it drives must share.

A PULSE checkpoint (agents' file format: a checksummed torch container around the agent's
state, agents/checkpoint.py) records this module as `extra["latent_decoder"]` = {"format",
"kwargs", "state_prefix", "settings"}: its constructor's arguments, where its weights sit in
the policy's state dict, and the settings.
"""
from __future__ import annotations

import hashlib
import io
import os
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch
from torch import nn

from .features import SELF_OBS_LAYOUT, layout_size

# As envs.base has it; not imported from there, which reaches this module (base -> render -> wrappers).
PROPRIO_DIM = layout_size(SELF_OBS_LAYOUT)
FORMAT = "smpl-envs-latent/1"
LOGVAR_RANGE = (-5.0, 2.0)  # log-variances are clamped here (PULSE's code)
_ACTIVATIONS = {"relu": nn.ReLU, "elu": nn.ELU, "silu": nn.SiLU, "tanh": nn.Tanh, "gelu": nn.GELU}
# agents.checkpoint's container: {"format", "sha256", "payload": uint8 tensor of the torch-saved state}.
_CONTAINER = "smpl-envs-agent-sha256/1"


def _mlp(in_dim: int, hidden: Sequence[int], out_dim: int, activation: str, out_gain: float) -> nn.Sequential:
    if activation not in _ACTIVATIONS:
        raise ValueError(f"activation must be one of {sorted(_ACTIVATIONS)}, got {activation!r}")
    if not isinstance(hidden, (list, tuple)) or not all(isinstance(h, int) and not isinstance(h, bool) and h > 0
                                                        for h in hidden):
        raise TypeError(f"hidden sizes must be a list of layer sizes such as [512, 256], got {hidden!r}")
    layers, dims = [], [in_dim, *hidden]
    for a, b in zip(dims[:-1], dims[1:]):
        layers += [nn.Linear(a, b), _ACTIVATIONS[activation]()]
    out = nn.Linear(dims[-1], out_dim)
    # A small last layer: the untrained decoder acts near the zero action, the prior near N(0, I).
    nn.init.orthogonal_(out.weight, gain=out_gain)
    nn.init.zeros_(out.bias)
    return nn.Sequential(*layers, out)


def split_gaussian(out: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(mean, log-variance clamped to LOGVAR_RANGE) of a network's (..., 2 d) output."""
    mu, logvar = out.chunk(2, dim=-1)
    return mu, logvar.clamp(*LOGVAR_RANGE)


class LatentDecoder(nn.Module):
    """The prior R(z | s_p) and the decoder D(a | s_p, z) of a PULSE latent space (module
    docstring), with the self observation's normalisation statistics as buffers.

    Args: proprio_dim (the self observation's size), latent_dim (z's, 32 in PULSE), action_dim
    (the env's, 69), prior_hidden and decoder_hidden (MLP sizes), activation, obs_clip.

    `forward(obs, a)` is the latent action map: obs (..., >= proprio_dim) raw task observations,
    a (..., latent_dim) latent actions -> env actions in [-1, 1]. Frozen (`freeze`) it is the
    fixed part of a downstream policy; agents.PULSE trains it, calling `prior` and `decode` on
    observations it normalised itself with the statistics it also keeps here (`set_statistics`).
    """

    def __init__(self, proprio_dim: int = PROPRIO_DIM, latent_dim: int = 32, action_dim: int = 69, *,
                 prior_hidden: Sequence[int] = (512, 256), decoder_hidden: Sequence[int] = (1024, 512),
                 activation: str = "silu", obs_clip: float | None = 5.0):
        super().__init__()
        for name, value in (("proprio_dim", proprio_dim), ("latent_dim", latent_dim), ("action_dim", action_dim)):
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        self.config = {"proprio_dim": proprio_dim, "latent_dim": latent_dim, "action_dim": action_dim,
                       "prior_hidden": list(prior_hidden), "decoder_hidden": list(decoder_hidden),
                       "activation": activation, "obs_clip": obs_clip}
        self.proprio_dim, self.latent_dim, self.action_dim = proprio_dim, latent_dim, action_dim
        self.obs_clip = None if obs_clip is None else float(obs_clip)
        # float64 as agents' running normaliser keeps them, so both normalise to the same numbers.
        self.register_buffer("obs_mean", torch.zeros(proprio_dim, dtype=torch.float64))
        self.register_buffer("obs_var", torch.ones(proprio_dim, dtype=torch.float64))
        self.prior_net = _mlp(proprio_dim, prior_hidden, 2 * latent_dim, activation, out_gain=0.01)
        self.decoder_net = _mlp(proprio_dim + latent_dim, decoder_hidden, action_dim, activation, out_gain=0.01)
        self.settings: dict[str, Any] | None = None  # the distillation env's policy settings, when known

    # ------------------------------------------------------------------ the networks
    def set_statistics(self, mean: torch.Tensor, var: torch.Tensor) -> None:
        """The self observation's normalisation statistics (the distillation run's)."""
        with torch.no_grad():
            self.obs_mean.copy_(mean)
            self.obs_var.copy_(var)

    def normalize(self, proprio: torch.Tensor) -> torch.Tensor:
        y = (proprio - self.obs_mean.to(proprio.dtype)) / torch.sqrt(self.obs_var.to(proprio.dtype) + 1e-8)
        return y.clamp(-self.obs_clip, self.obs_clip) if self.obs_clip else y

    def prior(self, nsp: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(mean, log-variance) of R(z | s_p) for normalised self observations."""
        return split_gaussian(self.prior_net(nsp))

    def decode(self, nsp: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        """The decoder's action (unclamped) for normalised self observations and latents z."""
        return self.decoder_net(torch.cat([nsp, z], -1))

    def proprio(self, obs: torch.Tensor) -> torch.Tensor:
        """The normalised self observation of raw task observations."""
        if obs.shape[-1] < self.proprio_dim:
            raise ValueError(f"observations have {obs.shape[-1]} features; the self observation alone has "
                             f"{self.proprio_dim}")
        return self.normalize(obs[..., :self.proprio_dim])

    def forward(self, obs: torch.Tensor, latent_action: torch.Tensor) -> torch.Tensor:
        """Env actions D(s_p, mu_prior(s_p) + a), clamped to [-1, 1], for raw observations."""
        nsp = self.proprio(obs)
        mu, _ = self.prior(nsp)
        return self.decode(nsp, mu + latent_action.to(mu.dtype)).clamp(-1.0, 1.0)

    def prior_std(self, obs: torch.Tensor) -> torch.Tensor:
        """The prior's standard deviation (..., latent_dim) on raw observations."""
        return torch.exp(0.5 * self.prior(self.proprio(obs))[1])

    def freeze(self) -> "LatentDecoder":
        self.requires_grad_(False)
        return self.eval()

    # ------------------------------------------------------------------ the checkpoint record
    def record(self, state_prefix: str, settings: dict | None) -> dict[str, Any]:
        """What a checkpoint holding this module in its policy under `state_prefix` records."""
        return {"format": FORMAT, "kwargs": dict(self.config), "state_prefix": state_prefix,
                "settings": dict(settings or {})}

    @classmethod
    def from_checkpoint(cls, path: str | os.PathLike, device: str | torch.device = "cpu") -> "LatentDecoder":
        """The frozen latent decoder of a PULSE checkpoint file (agents.PULSE.save), its
        `settings` set. A ValueError says when the file is none."""
        ckpt = read_checkpoint(path)
        record = (ckpt.get("extra") or {}).get("latent_decoder") if isinstance(ckpt, dict) else None
        if not isinstance(record, dict):
            raise ValueError(f"{path} holds no latent decoder (a PULSE checkpoint does: agents.PULSE.save)")
        if record.get("format") != FORMAT:
            raise ValueError(f"{path}: latent decoder of format {record.get('format')!r}; this version reads {FORMAT!r}")
        decoder = cls(**record["kwargs"])
        prefix = record["state_prefix"]
        decoder.load_state_dict({k[len(prefix):]: v for k, v in ckpt["policy"].items() if k.startswith(prefix)})
        decoder.settings = dict(record["settings"])
        return decoder.to(device).freeze()


def read_checkpoint(path: str | os.PathLike) -> dict:
    """The state an agents checkpoint file holds (its checksum verified), read with torch's safe
    loader onto the CPU. The reading side of agents/checkpoint.py's container, which smpl_envs
    cannot import; ValueError for a file that is no intact checkpoint."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no checkpoint at {path}")
    try:
        raw = torch.load(path, map_location="cpu", weights_only=True)
        if isinstance(raw, dict) and raw.get("format") == _CONTAINER:
            data = raw["payload"].numpy().tobytes()
            if hashlib.sha256(data).hexdigest() != raw["sha256"]:
                raise ValueError(f"{path} is corrupt: its payload fails its SHA-256 checksum")
            raw = torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
    except ValueError:
        raise
    except Exception as e:
        raise ValueError(f"{path} is not a readable checkpoint: {e}") from None
    return raw


def as_latent_decoder(source) -> LatentDecoder:
    """A `LatentDecoder` from a PULSE checkpoint path, a `LatentDecoder`, or an object that has
    one as `latent_decoder` (agents.PULSE, its policy, a latent-task policy)."""
    if isinstance(source, LatentDecoder):
        return source
    if isinstance(source, (str, os.PathLike)):
        return LatentDecoder.from_checkpoint(source)
    decoder = getattr(source, "latent_decoder", None)
    if isinstance(decoder, LatentDecoder):
        return decoder
    raise TypeError(f"expected a PULSE checkpoint path or a LatentDecoder (or an object with one as "
                    f"`latent_decoder`, such as agents.PULSE), got {type(source).__name__}")


class PriorSampler:
    """A policy for a `LatentAction` env that samples z from the prior every step: the latent
    action noise_scale x sigma_prior(s_p) x eps, eps ~ N(0, I) from a seeded generator (so
    z = mu_prior + that). noise_scale 0 acts the prior's mean. Takes one observation or a batch."""

    def __init__(self, decoder, seed: int | None = 0, noise_scale: float = 1.0):
        self.decoder = as_latent_decoder(decoder)
        if not (np.isfinite(noise_scale) and noise_scale >= 0):
            raise ValueError(f"noise_scale must be a non-negative number, got {noise_scale!r}")
        self.noise_scale = float(noise_scale)
        self.rng = np.random.default_rng(seed)

    def __call__(self, obs):
        torch_in = isinstance(obs, torch.Tensor)
        x = torch.as_tensor(obs, dtype=torch.float32)
        single = x.ndim == 1
        x = x.reshape(-1, x.shape[-1])
        device = next(self.decoder.buffers()).device
        with torch.no_grad():
            std = self.decoder.prior_std(x.to(device))
        eps = torch.as_tensor(self.rng.standard_normal(std.shape), dtype=std.dtype, device=device)
        a = self.noise_scale * std * eps
        a = a[0] if single else a
        return a.to(obs.device) if torch_in else a.cpu().numpy()


__all__ = ["LatentDecoder", "PriorSampler", "as_latent_decoder", "read_checkpoint", "split_gaussian",
           "LOGVAR_RANGE", "FORMAT"]
