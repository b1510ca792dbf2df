"""How far a latent action moves the right hand, held still or redrawn every step.

`latent_authority.py` measures one step: how much a latent action changes the decoded action.
A task policy steers over many steps, so this measures what Reach needs: the humanoid starts at
rest in SMPL/Reach-v0 behind `LatentAction(pulse)`, stands `--settle` steps with a = 0, then
every world but the first acts `--steps` steps with its own latent action of per-dimension std s

- held: one a ~ N(0, s^2 I) for the whole window (a policy that means to go somewhere), or
- white: a fresh a ~ N(0, s^2 I) every step (what PPO's Gaussian exploration adds to its mean);

and the right hand's end position is compared with the first world's (a = 0: the prior's mean).
Worlds that fall are counted and left out of the distances. If held latents move the hand tens
of centimetres and white ones a few, a latent task is held by how its exploration is shaped in
time, not by the decoder's gain.

With --search N it also asks whether held latents can do Reach's job at all: for N targets drawn
as Reach-v0 draws them (around the resting body), the cross-entropy method searches a latent
plan (--segments pieces of --segment-steps steps, each piece one held a) that brings the hand
closest to the target within the window, every world of an iteration one candidate plan from
the same start; it reports the closest approach per target, against a = 0. A plan found here is
open loop, so it bounds from below what a closed-loop task policy could do.

With --zero-eval it also runs Reach-v0's evaluation protocol (32 seeded episodes, starts on the
walk and run clips as the reach recipes train) with a = 0, the prior's mean: the floor a trained
latent task policy has to beat.

    python benchmarks/latent_steering.py pulse --worlds 64 --search 24 --zero-eval --out runs/steering_pulse.json
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

STDS = (0.37, 1.0, 2.0)


def _reach_env(decoder, worlds: int, steps: int):
    import gymnasium as gym

    import smpl_envs  # noqa: F401  (registers the ids)
    from smpl_envs.wrappers import LatentAction

    # No target redraw inside the window: a search is about one target.
    return LatentAction(gym.make_vec("SMPL/Reach-v0", num_envs=worlds, max_episode_steps=steps + 1,
                                     resample_interval=(steps + 1, steps + 1)), decoder)


def run(decoder, worlds: int, settle: int, steps: int, std: float, held: bool, seed: int) -> dict:
    from smpl_envs.envs.reach import HAND

    env = _reach_env(decoder, worlds, settle + steps)
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    dim = env.single_action_space.shape[0]
    zero = np.zeros((worlds, dim), np.float32)
    fell = np.zeros(worlds, bool)
    for _ in range(settle):
        _, _, term, _, _ = env.step(zero)
        fell |= np.asarray(term)
    a = (rng.standard_normal((worlds, dim)) * std).astype(np.float32)
    start = np.asarray(env.unwrapped.sim.bodies.pos[:, HAND]).copy()
    for _ in range(steps):
        if not held:
            a = (rng.standard_normal((worlds, dim)) * std).astype(np.float32)
        a[0] = 0.0
        _, _, term, _, _ = env.step(a)
        fell |= np.asarray(term)
    end = np.asarray(env.unwrapped.sim.bodies.pos[:, HAND])
    env.close()
    if fell[0]:
        raise RuntimeError("the a = 0 world fell: the prior's mean does not stand here, nothing to compare with")
    keep = ~fell
    keep[0] = False
    shift = np.linalg.norm(end[keep] - end[0], axis=-1)
    travel = np.linalg.norm(end[keep] - start[keep], axis=-1)
    return {"std": std, "held": held, "worlds": int(keep.sum()), "fell": float(fell[1:].mean()),
            "shift_median": float(np.median(shift)), "shift_p90": float(np.quantile(shift, 0.9)),
            "hand_travel_median": float(np.median(travel)),
            "baseline_hand_travel": float(np.linalg.norm(end[0] - start[0]))}


def search(decoder, worlds: int, settle: int, segments: int, segment_steps: int, iterations: int,
           init_std: float, elites: int, seed: int) -> dict:
    """The cross-entropy method over held-latent plans for one target (module docstring): the
    closest approach of the hand (m) over the window for the best plan found and for a = 0."""
    from smpl_envs.envs.reach import HAND

    env = _reach_env(decoder, worlds, settle + segments * segment_steps)
    dim = env.single_action_space.shape[0]
    rng = np.random.default_rng(seed)
    mean, std = np.zeros((segments, dim)), np.full((segments, dim), init_std)
    target, best, best_plan, zero_dist, history = None, np.inf, None, None, []
    for it in range(iterations):
        env.reset(seed=seed)  # the same resting start every iteration
        task = env.unwrapped
        if target is None:
            target = np.asarray(task.target[0]).copy()
        for _ in range(settle):
            env.step(np.zeros((worlds, dim), np.float32))
        task.target[:] = target
        plans = mean + std * rng.standard_normal((worlds, segments, dim))
        plans[0] = 0.0 if it == 0 else mean  # world 0: a = 0 first, then the current mean
        closest, fell = np.full(worlds, np.inf), np.zeros(worlds, bool)
        for k in range(segments * segment_steps):
            _, _, term, _, _ = env.step(plans[:, k // segment_steps].astype(np.float32))
            fell |= np.asarray(term)
            d = np.linalg.norm(np.asarray(task.sim.bodies.pos[:, HAND]) - target, axis=-1)
            closest = np.minimum(closest, np.where(fell, np.inf, d))
        if it == 0:
            zero_dist = float(closest[0])
        if closest.min() < best:
            best, best_plan = float(closest.min()), plans[int(closest.argmin())]
        history.append(best)
        top = np.argsort(closest)[:elites]
        mean, std = plans[top].mean(0), np.maximum(plans[top].std(0), 0.05)
    env.close()
    return {"target": target.tolist(), "zero_closest": zero_dist, "best_closest": best, "history": history,
            # How large a latent the plan needed: PULSE's task policies keep |mu| within 1 (bounds loss).
            "plan_abs_mean": float(np.abs(best_plan).mean()), "plan_abs_max": float(np.abs(best_plan).max())}


def zero_eval(decoder) -> dict:
    """Reach-v0's evaluation of the a = 0 policy (module docstring)."""
    import smpl_envs
    from smpl_envs.latent import as_latent_decoder

    dec = as_latent_decoder(decoder)

    def policy(obs):
        o = torch.as_tensor(obs, dtype=torch.float32)
        with torch.no_grad():
            return dec(o, torch.zeros(len(o), dec.latent_dim)).numpy()

    r = smpl_envs.evaluate(policy, "SMPL/Reach-v0", motions=["walk", "run"], num_envs=8, progress=False)
    return {k: r.summary[k] for k in ("no_fall", "hand_distance", "targets_reached")}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("checkpoint", help="a PULSE checkpoint (.pt), a run directory or a shipped name")
    p.add_argument("--worlds", type=int, default=64)
    p.add_argument("--settle", type=int, default=10, help="steps at a = 0 before the window")
    p.add_argument("--steps", type=int, default=30, help="the window: 30 steps = 1 s")
    p.add_argument("--stds", type=float, nargs="+", default=list(STDS))
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--search", type=int, default=0, metavar="N", help="also search latent plans for N Reach targets")
    p.add_argument("--segments", type=int, default=3)
    p.add_argument("--segment-steps", type=int, default=10)
    p.add_argument("--iterations", type=int, default=8)
    p.add_argument("--init-std", type=float, default=0.5, help="the search's first spread (per dimension)")
    p.add_argument("--elites", type=int, default=8)
    p.add_argument("--skip-shift", action="store_true", help="leave out the held/white comparison")
    p.add_argument("--zero-eval", action="store_true", help="also evaluate a = 0 on Reach-v0's protocol")
    p.add_argument("--out", type=Path)
    args = p.parse_args(argv)
    if args.worlds < 2:
        p.error("--worlds must be at least 2: world 0 is the a = 0 reference")

    from agents.recipes import find_checkpoint

    torch.set_num_threads(1)
    path = find_checkpoint(args.checkpoint)
    result = {"checkpoint": str(args.checkpoint), "steps": args.steps}
    if not args.skip_shift:
        rows = result["rows"] = [run(str(path), args.worlds, args.settle, args.steps, s, held, args.seed)
                                 for s in args.stds for held in (True, False)]
        print(f"{args.checkpoint}: right hand after {args.steps} steps of a latent action, against a = 0 "
              f"({args.worlds - 1} worlds each)\n")
        print("| latent action | per-dim std | fell | hand shift vs a = 0, median (m) | 90th pct (m) |")
        print("|---|---|---|---|---|")
        for r in rows:
            print(f"| {'held' if r['held'] else 'white'} | {r['std']:g} | {100 * r['fell']:.0f} % | "
                  f"{r['shift_median']:.3f} | {r['shift_p90']:.3f} |")
    if args.search:
        from tqdm import tqdm

        found = result["search"] = [
            search(str(path), args.worlds, args.settle, args.segments, args.segment_steps, args.iterations,
                   args.init_std, args.elites, args.seed + k)
            for k in tqdm(range(args.search), desc="targets", unit="target")]
        best = np.array([f["best_closest"] for f in found])
        zero = np.array([f["zero_closest"] for f in found])
        window = args.segments * args.segment_steps
        print(f"\nheld-latent plans ({args.segments} x {args.segment_steps} steps) for {args.search} Reach targets, "
              f"closest hand approach within {window} steps:")
        print(f"  a = 0: median {np.median(zero):.3f} m; searched: median {np.median(best):.3f} m, "
              f"within 0.1 m {100 * np.mean(best < 0.1):.0f} %, within 0.2 m {100 * np.mean(best < 0.2):.0f} %; "
              f"the plans' |a|: mean {np.mean([f['plan_abs_mean'] for f in found]):.2f}, "
              f"largest {np.max([f['plan_abs_max'] for f in found]):.2f}")
    if args.zero_eval:
        z = result["zero_policy_reach"] = zero_eval(str(path))
        print(f"\nReach-v0's evaluation with a = 0 (the prior's mean): {100 * z['no_fall']:.0f} % without a fall, "
              f"hand distance {z['hand_distance']:.2f} m, {100 * z['targets_reached']:.1f} % of targets reached")
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
