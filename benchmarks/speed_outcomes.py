"""Where a Speed policy's error comes from: every step of seeded episodes with its commanded speed,
the time since the command was drawn, the turn it asked for, and the speed the pelvis made along
the commanded direction. Speed's protocol gives one mean error; this splits it by commanded speed
(can the body run that fast?), by time since the draw (is it the turn and the speed-up, or the
holding?) and by the episode's first command (from the standing start) against later ones.

    python benchmarks/speed_outcomes.py runs/speed_pulse [--checkpoint last] [--episodes 64]

Deterministic actions, the checkpoint's own env settings, episodes seeded from --seed on (a
different stream from the protocol's). The speed made is the pelvis' horizontal displacement over
one control step along the target direction, smoother than the instantaneous velocity the reward
reads; the error is the env's own, |v* - v_x|.
"""

from __future__ import annotations

import numpy as np
from policy_episodes import open_policy_env

SPEED_BINS = (0.0, 1.0, 2.0, 3.0, 4.0, 5.0)
SINCE_BINS = (0.0, 1.0, 2.0, 3.0, np.inf)


def summarise(rows: np.ndarray) -> list[str]:
    """Markdown lines for per-step rows (commanded speed, error, seconds since the draw, turn asked
    at the draw (degrees, 0-180), speed made along the target (m/s), 1 on an episode's first
    command)."""
    speed, err, since, turn, made, first = rows.T
    lines = ["| steps | share | mean error (m/s) | speed made, mean (m/s) | after 2 s: error (m/s) | after 2 s: speed made, 90th pct (m/s) |",
             "|---|---|---|---|---|---|"]

    def row(name, m):
        if not m.any():
            return
        held = m & (since >= 2.0)
        tail = (f"{err[held].mean():.2f} | {np.percentile(made[held], 90):.2f}" if held.any() else "- | -")
        lines.append(f"| {name} | {m.mean():.1%} | {err[m].mean():.2f} | {made[m].mean():.2f} | {tail} |")

    row("all", np.ones(len(rows), bool))
    for lo, hi in zip(SPEED_BINS[:-1], SPEED_BINS[1:]):
        row(f"commanded {lo:g}-{hi:g} m/s", (speed >= lo) & (speed < hi))
    for lo, hi in zip(SINCE_BINS[:-1], SINCE_BINS[1:]):
        row(f"{lo:g}-{hi:g} s after the draw" if np.isfinite(hi) else f"{lo:g} s or more after the draw",
            (since >= lo) & (since < hi))
    row("turn asked under 45 deg", turn < 45)
    row("turn asked over 135 deg", turn > 135)
    row("the episode's first command (standing start)", first > 0)
    row("later commands", first == 0)
    return lines


def _columns():
    """The observation's target direction and target speed slices (Speed-v0's layout)."""
    from smpl_envs.envs.speed import SpeedVecEnv
    from smpl_envs.features import SELF_OBS_LAYOUT, layout_slices

    where = layout_slices({"self": SELF_OBS_LAYOUT, **SpeedVecEnv.task_layout})
    return where["task/target_dir"], where["task/target_speed"]


def _turn(obs: np.ndarray, dir_cols: slice) -> np.ndarray:
    """The turn (degrees, 0-180) from the heading to the target direction the observation shows."""
    cos_sin = obs[:, dir_cols]
    return np.degrees(np.abs(np.arctan2(cos_sin[:, 1], cos_sin[:, 0])))


def main(argv=None) -> None:
    from smpl_envs.envs.base import CONTROL_FPS

    args, agent, ckpt, env, n = open_policy_env(__doc__, "SMPL/Speed-v0", argv)
    dir_cols, speed_col = _columns()
    rows, falls, done, seed, dt = [], 0, 0, args.seed, 1.0 / CONTROL_FPS
    while done < args.episodes:
        take = min(n, args.episodes - done)
        obs, info = env.reset(seed=seed)
        seed += 1
        # Per world: the command's step of draw, the turn it asked (the observation shows a new
        # command, its direction in the heading frame, before the step that first measures it) and
        # whether it is the episode's first.
        shown, turn = obs[:, speed_col].copy(), _turn(obs, dir_cols)
        drawn, first = np.zeros(n, int), np.ones(n, bool)
        pelvis = np.asarray(info["body_pos"])[:, 0, :2].copy()
        alive, t = np.arange(n) < take, 0
        while alive.any():  # the env truncates at its episode length (10 s)
            action, _ = agent.predict(obs, deterministic=True)
            obs, _, term, trunc, info = env.step(action)
            t += 1
            now = np.asarray(info["body_pos"])[:, 0, :2]
            # info holds the command this step was measured against
            speed, direction = np.asarray(info["target_speed"]), np.asarray(info["target_dir"])
            made = np.einsum("ij,ij->i", now - pelvis, direction) / dt
            err = np.asarray(info["speed_error"])
            rows.append(np.stack([speed, err, (t - 1 - drawn) * dt, turn, made, first], -1)[alive])
            falls += int((term & alive).sum())
            alive &= ~(term | trunc)
            changed = (obs[:, speed_col] != shown)[:, 0]  # drawn after this step: the next one is its first
            turn, drawn = np.where(changed, _turn(obs, dir_cols), turn), np.where(changed, t, drawn)
            first &= ~changed
            shown, pelvis = obs[:, speed_col].copy(), now.copy()
        done += take
    env.close()
    table = np.concatenate(rows).astype(float)
    print(f"{ckpt} ({agent.num_timesteps:,} samples), {done} episodes ({falls} fell), {len(table)} steps")
    print("\n".join(summarise(table)))


if __name__ == "__main__":
    main()
