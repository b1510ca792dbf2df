"""How a Strike policy's episodes end: at full length, on a fall, or on a foul (a body other than
the right hand, wrist or elbow touching the box), with or without the box toppled, which bodies
foul, and when boxes go down. Strike's protocol counts falls and fouls together ("no_fall"); this
splits them, which is what tells a policy that trips from one that walks into the box.

    python benchmarks/strike_outcomes.py runs/strike_pulse_linear [--checkpoint last] [--episodes 64]

Deterministic actions, the checkpoint's own env settings, episodes seeded from --seed on (a
different stream from the protocol's, so the two are independent samples).
"""

from __future__ import annotations

import collections

import numpy as np
from policy_episodes import open_policy_env


def main(argv=None) -> None:
    from smpl_envs.envs.base import CONTROL_FPS
    from smpl_envs.envs.strike import STRIKERS
    from smpl_envs.humanoid.skeleton import BODY_NAMES

    args, agent, ckpt, env, n = open_policy_env(__doc__, "SMPL/Strike-v0", argv)
    ends, fouls, topple_s = collections.Counter(), collections.Counter(), []
    done, seed = 0, args.seed
    while done < args.episodes:
        obs, _ = env.reset(seed=seed)
        seed += 1
        alive, end, toppled_at = np.ones(n, bool), np.array(["full"] * n, object), np.full(n, -1)
        t = 0
        while alive.any():  # the env truncates at its episode length (10 s)
            t += 1
            action, _ = agent.predict(obs, deterministic=True)
            obs, _, term, trunc, info = env.step(action)
            toppled_at[(toppled_at < 0) & alive & np.asarray(info["toppled"])] = t
            touching = np.asarray(info["touching"]).copy()
            touching[:, STRIKERS] = False
            for i in np.flatnonzero(alive & term):
                end[i] = "foul" if touching[i].any() else "fall"
                fouls.update(BODY_NAMES[j] for j in np.flatnonzero(touching[i]))
            alive &= ~(term | trunc)
        take = min(n, args.episodes - done)
        for i in range(take):
            ends[(end[i], bool(toppled_at[i] > 0))] += 1
            if toppled_at[i] > 0:
                topple_s.append(toppled_at[i] / CONTROL_FPS)
        done += take
    env.close()

    print(f"{ckpt} ({agent.num_timesteps:,} samples), {done} episodes")
    print("| episode ends | box toppled | box standing | all |\n|---|---|---|---|")
    for kind in ("full", "fall", "foul"):
        a, b = ends[(kind, True)], ends[(kind, False)]
        print(f"| {kind} | {a} | {b} | {a + b} ({(a + b) / done:.1%}) |")
    top = sum(v for (k, t), v in ends.items() if t)
    print(f"| all | {top} ({top / done:.1%}) | {done - top} | {done} |")
    if fouls:
        print("fouling bodies:", ", ".join(f"{k} {v}" for k, v in fouls.most_common()))
    if topple_s:
        print(f"box down after {np.median(topple_s):.1f} s (median; quartiles {np.percentile(topple_s, 25):.1f}"
              f"-{np.percentile(topple_s, 75):.1f} s)")


if __name__ == "__main__":
    main()
