"""How much a PULSE checkpoint's latent z steers its decoder.

A latent task policy acts through z = mu_prior(s_p) + a, so it can only do what the decoder lets
z do. This measures that on the states the student meets as an imitator (SMPL/Imitation-v0 with
the checkpoint's own settings, z = the encoder's mean):

- the action change the imitation signal makes through z: |D(s_p, mu_E) - D(s_p, mu_R)|, mean
  over worlds, steps and the 69 action dimensions (actions in [-1, 1], so 0.01 is 0.5 % of a
  joint's range);
- the change a latent action a ~ N(0, std^2) makes, for the task policies' std 0.37 (PULSE's
  exp(-1)) and others;
- the scale of the encoder's offsets mu_E - mu_R and the encoder's and prior's std;
- with --eval: imitation on the motion set with z = mu_E (the student) and z = mu_R (the prior's
  mean, no reference information): if the two succeed alike, z carries next to nothing.

    python benchmarks/latent_authority.py agents/pretrained/pulse.pt --eval --out runs/authority.json
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

NOISE_STDS = (0.1, 0.37, 1.0, 2.0)


def collect(model, motions: str, worlds: int, steps: int, seed: int):
    """(self observations, encoder means, prior means, encoder stds, prior stds) of the student
    imitating `motions` with z = its encoder's mean, `steps` steps of `worlds` worlds."""
    import gymnasium as gym

    pol = model.policy
    env = gym.make_vec(model.env_id, num_envs=worlds, **{**model.env_kwargs, "motions": motions})
    obs, _ = env.reset(seed=seed)
    rows = []
    with torch.no_grad():
        for _ in range(steps):
            o = torch.as_tensor(obs, dtype=torch.float32)
            mu, logvar, prior_mu, prior_logvar = pol.distributions(pol.normalize(o))
            rows.append((o, mu, prior_mu, torch.exp(0.5 * logvar), torch.exp(0.5 * prior_logvar)))
            obs, *_ = env.step(pol.env_action(mu, o).numpy())
    env.close()
    return [torch.cat(c) for c in zip(*rows)]


def authority(model, obs, mu, prior_mu, seed: int) -> dict:
    pol = model.policy

    def act(z):
        return pol.env_action(z, obs)

    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        base = act(prior_mu)
        out = {"signal_effect": float((act(mu) - base).abs().mean())}
        for std in NOISE_STDS:
            a = torch.randn(prior_mu.shape, generator=g) * std
            out[f"noise_effect_std_{std}"] = float((act(prior_mu + a) - base).abs().mean())
    off = (mu - prior_mu).numpy()
    out.update(offset_abs_mean=float(np.abs(off).mean()), offset_std_per_dim_mean=float(off.std(0).mean()),
               offset_std_per_dim_max=float(off.std(0).max()))
    return out


def imitation(model, motions: str, worlds: int, use_prior: bool):
    import smpl_envs

    pol = model.policy

    def policy(obs):
        o = torch.as_tensor(obs, dtype=torch.float32)
        with torch.no_grad():
            mu, _, prior_mu, _ = pol.distributions(pol.normalize(o))
            return pol.env_action(prior_mu if use_prior else mu, o).numpy()

    from smpl_envs.policy_settings import task_class

    # The task's evaluation protocol decides its own episode rules (termination, starts).
    kwargs = task_class(model.env_id).evaluation.eval_kwargs(model.env_kwargs)
    kwargs.pop("motions", None)
    return smpl_envs.evaluate(policy, model.env_id, motions=motions, num_envs=worlds, env_kwargs=kwargs)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("checkpoint", help="a PULSE checkpoint (.pt), a run directory or a shipped name")
    p.add_argument("--motions", default="corpus:test")
    p.add_argument("--worlds", type=int, default=16)
    p.add_argument("--steps", type=int, default=100)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--eval", action="store_true", help="also imitate with z = encoder mean and z = prior mean")
    p.add_argument("--out", type=Path, help="write the figures as JSON here")
    args = p.parse_args(argv)

    import agents
    from agents.recipes import find_checkpoint

    torch.set_num_threads(1)
    model = agents.load(find_checkpoint(args.checkpoint))
    if not hasattr(model.policy, "encoder"):
        p.error(f"{args.checkpoint} holds a {type(model.policy).__name__}, not a PULSE policy with an encoder")
    obs, mu, prior_mu, enc_std, prior_std = collect(model, args.motions, args.worlds, args.steps, args.seed)
    result = {"checkpoint": str(args.checkpoint), "motions": args.motions, "states": len(obs),
              **authority(model, obs, mu, prior_mu, args.seed),
              "encoder_std": float(enc_std.mean()), "prior_std": float(prior_std.mean())}
    print(f"{args.checkpoint}: {len(obs)} states of {args.motions}")
    print("| what | mean abs action change (actions in [-1, 1]) |\n|---|---|")
    print(f"| z from the prior's mean to the encoder's (the imitation signal) | {result['signal_effect']:.4f} |")
    for std in NOISE_STDS:
        print(f"| a ~ N(0, {std}^2) added to the prior's mean | {result[f'noise_effect_std_{std}']:.4f} |")
    print(f"\nencoder offsets |mu_E - mu_R|: mean {result['offset_abs_mean']:.3f}, per-dimension std "
          f"{result['offset_std_per_dim_mean']:.3f} (largest {result['offset_std_per_dim_max']:.3f}); "
          f"encoder std {result['encoder_std']:.3f}, prior std {result['prior_std']:.3f}")
    if args.eval:
        for name, use_prior in (("encoder_mean", False), ("prior_mean", True)):
            r = imitation(model, args.motions, args.worlds, use_prior)
            result[f"imitation_{name}"] = {k: r.summary.get(k) for k in ("success_rate", "mpjpe_g", "all_mpjpe_g")}
            print(f"imitation with z = {name.replace('_', ' ')}: success {100 * r.summary['success_rate']:.1f} %, "
                  f"E_g-mpjpe {r.summary.get('mpjpe_g', float('nan')):.1f} mm on the clips followed, "
                  f"{r.summary.get('all_mpjpe_g', float('nan')):.1f} mm over every frame tracked")
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
