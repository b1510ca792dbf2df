"""Which Reach targets a policy reaches: every target of seeded episodes with where it stood when
drawn (in front of the pelvis or behind, to the right hand's side or across the body, its height),
the hand's closest approach, and how long the hand took to come within 0.1 m. Reach's protocol
gives one rate and a mean distance; this says where the misses are and how much of the mean
distance is the time spent getting there.

    python benchmarks/reach_outcomes.py runs/reach_pulse [--checkpoint last] [--episodes 64]

Deterministic actions, the checkpoint's own env settings, episodes seeded from --seed on (a
different stream from the protocol's). Targets the time limit cut short before the hand came
within 0.1 m are left out, as the protocol does.
"""

from __future__ import annotations

import numpy as np
from policy_episodes import open_policy_env


def summarise(rows: np.ndarray, fps: float) -> list[str]:
    """Markdown lines for per-target rows (x, y, z local to the pelvis at the draw, target height
    above the floor, closest approach (m), steps to within 0.1 m or -1)."""
    from smpl_envs.envs.reach import REACHED

    x, y, height, closest, steps = rows[:, 0], rows[:, 1], rows[:, 3], rows[:, 4], rows[:, 5]
    groups = [("all", np.ones(len(rows), bool)),
              ("in front (x > 0)", x > 0), ("behind (x < 0)", x < 0),
              ("right-hand side (y < 0)", y < 0), ("across the body (y > 0)", y > 0),
              ("low (height < 0.8 m)", height < 0.8), ("middle (0.8-1.4 m)", (height >= 0.8) & (height < 1.4)),
              ("high (height >= 1.4 m)", height >= 1.4)]
    lines = [f"| targets | count | reached (within {REACHED} m) | closest approach, median (m) | time to reach, median (s) |",
             "|---|---|---|---|---|"]
    for name, m in groups:
        if not m.any():
            continue
        hit = steps[m] >= 0
        time = f"{np.median(steps[m][hit]) / fps:.2f}" if hit.any() else "-"
        lines.append(f"| {name} | {m.sum()} | {hit.mean():.1%} | {np.median(closest[m]):.3f} | {time} |")
    return lines


def main(argv=None) -> None:
    from smpl_envs.envs.base import CONTROL_FPS
    from smpl_envs.envs.reach import REACHED

    args, agent, ckpt, env, n = open_policy_env(__doc__, "SMPL/Reach-v0", argv)
    rows, falls, done, seed = [], 0, 0, args.seed
    while done < args.episodes:
        take = min(n, args.episodes - done)
        obs, info = env.reset(seed=seed)
        seed += 1
        # Per world, the current target: where it stood when drawn (the observation's last 3
        # entries are it relative to the pelvis in the heading frame, exact at the step it
        # appears), its height, the hand's closest approach, the step drawn and the step reached.
        index = np.asarray(info["target_index"]).copy()
        local, height = obs[:, -3:].copy(), np.asarray(info["target_pos"])[:, 2].copy()
        closest, drawn, reached = np.full(n, np.inf), np.zeros(n, int), np.full(n, -1)
        alive, t = np.ones(n, bool), 0

        def settle(i):
            if i < take:
                rows.append([*local[i], height[i], closest[i], reached[i] - drawn[i] if reached[i] >= 0 else -1])

        while alive.any():  # the env truncates at its episode length (10 s)
            action, _ = agent.predict(obs, deterministic=True)
            obs, _, term, trunc, info = env.step(action)
            t += 1
            new, dist = np.asarray(info["target_index"]), np.asarray(info["hand_distance"])
            for i in np.flatnonzero(alive & (new != index)):  # a new target: the last one is settled
                settle(i)
                local[i], height[i] = obs[i, -3:], np.asarray(info["target_pos"])[i, 2]
                closest[i], drawn[i], reached[i], index[i] = np.inf, t, -1, new[i]
            closest = np.where(alive, np.minimum(closest, dist), closest)
            reached = np.where(alive & (reached < 0) & (dist < REACHED), t, reached)
            for i in np.flatnonzero(alive & (term | trunc)):
                falls += bool(term[i] and i < take)
                if term[i] or reached[i] >= 0:  # a target the time limit cut short says nothing
                    settle(i)
            alive &= ~(term | trunc)
        done += take
    env.close()
    table = np.array(rows, float).reshape(-1, 6)
    print(f"{ckpt} ({agent.num_timesteps:,} samples), {done} episodes ({falls} fell), {len(table)} targets")
    print("\n".join(summarise(table, CONTROL_FPS)))


if __name__ == "__main__":
    main()
