"""How far a simulated body follows the get-up clips (smpl_envs.motion.getup): the clips are
kinematic, and this measures whether the humanoid can do them, phase by phase.

    python benchmarks/getup_follow.py                          # PD on the reference alone
    python benchmarks/getup_follow.py --checkpoint runs/tracker_getup

Each clip is followed from its first frame (the body placed in the reference's lying pose) in
SMPL/Imitation-v0 with no early termination, either by the zero residual action (the PD targets
are the reference's joint angles: what the clip asks of the humanoid with no feedback at all) or
by a trained imitation policy, deterministic, in the settings it was trained with. Per clip:

- followed: frames until the mean body distance to the reference first exceeds `--threshold`
  (0.5 m), of the clip's frames;
- lost in: the phase of the clip at that frame (the generator's phases, from the clip's
  parameters in the corpus manifest, or "-" when it is followed to the end);
- d <phase>: the mean body distance (m) over each phase, while still followed;
- from the back, whether and when the simulated body was first face down (the pelvis' forward
  axis pointing more than 30 deg below level): a body that stays on its back through a roll is
  still within 0.5 m of it for most of the clip, so "followed" alone does not say it rolled.

A second table is the reference's own: per phase, the smallest margin of its zero-moment point
inside the hull of its floor contacts (`plausibility.zmp_margin`; m, negative: outside) and the
frames it spends outside. A phase the ZMP leaves the hull for several frames asks for a balance
no body has, and PD, a tracker, or anything imitating it closely falls there.

The first table's last row gives the mean frames followed and the share followed to the end. The PD
row is the reference's feasibility without a learnt correction: a phase PD loses at once is one a
tracker must learn a balance for (the weight shifted back over the feet in the crouch), or, where
it is kinematically impossible for a body with its weight on its hands, one the generator should
change (the knees sliding under the hips, `getup._KNEE_SLIDE`, and the bear-stance rise that
replaced a lunge whose ZMP left the hull came from here).
"""
from __future__ import annotations

import argparse
import json

import gymnasium as gym
import numpy as np

import smpl_envs  # noqa: F401 (registers the ids)
from smpl_envs.features import facing_height
from smpl_envs.motion import MotionLib
from smpl_envs.motion import corpus as C
from smpl_envs.motion import getup as gu
from smpl_envs.motion.motion import FPS
from smpl_envs.motion.plausibility import zmp_margin

ENV_ID = "SMPL/Imitation-v0"


GETUP_ARGS = ("start", "side", "roll", *gu.RANGES["getup"])  # what a manifest record gives getup()


def phase_frames(params: dict) -> dict[str, tuple[int, int]]:
    """{phase: (first frame, end frame)} of the get-up drawn with `params` (its manifest record)."""
    return {p: (int(round(a * FPS)), int(round(b * FPS)))
            for p, (a, b) in gu.phases(**{k: params[k] for k in GETUP_ARGS}).items()}


def follow(lib: MotionLib, act, env_kwargs: dict) -> tuple[np.ndarray, np.ndarray]:
    """(clips, frames) mean body distance to the reference and the simulated body's
    `facing_height`, NaN past a clip's end."""
    n, frames = lib.num_motions, int(lib.lengths.max())
    env = gym.make_vec(ENV_ID, num_envs=n, motions=lib, termination_distance=None, autoreset_mode="Disabled",
                       **env_kwargs)
    try:
        obs, info = env.reset(seed=0, options={"start": "beginning", "motion_ids": np.arange(n)})
        dist, facing = np.full((n, frames), np.nan), np.full((n, frames), np.nan)
        for t in range(1, frames):
            obs, _, _, _, info = env.step(act(obs))
            body = np.asarray(info["body_pos"])
            d = np.linalg.norm(body - np.asarray(info["ref_body_pos"]), axis=-1).mean(-1)
            dist[:, t] = np.where(t < lib.lengths, d, np.nan)
            facing[:, t] = np.where(t < lib.lengths, facing_height(body), np.nan)
    finally:
        env.close()
    return dist, facing


def report(lib: MotionLib, manifest: dict, dist: np.ndarray, threshold: float,
           facing: np.ndarray | None = None) -> list[dict]:
    """Per clip: frames followed, the phase it was lost in, the mean distance per phase and, from
    the back with `facing` given, the first frame the simulated body was face down ("turned",
    None if never): a body can stay within the distance threshold of a roll it never made."""
    rows = []
    for i, name in enumerate(lib.names):
        spans = phase_frames(manifest[name])
        length = int(lib.lengths[i])
        over = np.flatnonzero(dist[i, :length] > threshold)
        lost = int(over[0]) if len(over) else length
        lost_in = "-" if lost == length else next((p for p, (a, b) in spans.items() if a <= lost < b), "end")
        means = {p: float(np.nanmean(dist[i, a:min(b, lost)])) if a < lost else None for p, (a, b) in spans.items()}
        row = {"clip": name, "start": manifest[name]["start"], "followed": lost, "frames": length,
               "lost_in": lost_in, "distance": means}
        if facing is not None and manifest[name]["start"] == "back":
            down = np.flatnonzero(facing[i, :length] < -0.5)
            row["turned"] = int(down[0]) if len(down) else None
        rows.append(row)
    return rows


def table(rows: list[dict], title: str) -> str:
    seen = {p for r in rows for p in r["distance"]}
    phases = [p for p in gu.phases("back") if p in seen]  # the back start has every phase, in order
    head = f"{'clip':<18}{'start':<7}{'followed':>12}  {'lost in':<8}" + "".join(f"{'d ' + p:>9}" for p in phases)
    lines = [title, head, "-" * len(head)]
    for r in rows:
        d = "".join(f"{r['distance'][p]:>9.2f}" if r["distance"].get(p) is not None else f"{'':>9}" for p in phases)
        lines.append(f"{r['clip']:<18}{r['start']:<7}{r['followed']:>6}/{r['frames']:<5}  {r['lost_in']:<8}{d}")
    full = np.mean([r["followed"] == r["frames"] for r in rows])
    lines.append(f"mean frames followed {np.mean([r['followed'] for r in rows]):.0f}; "
                 f"followed to the end {100 * full:.0f} %")
    backs = [r for r in rows if "turned" in r]
    if backs:
        turned = [r["turned"] for r in backs if r["turned"] is not None]
        lines.append(f"from the back, turned face down: {len(turned)} of {len(backs)}"
                     + (f" (first frame {min(turned)}-{max(turned)})" if turned else ""))
    return "\n".join(lines)


def zmp_table(raws, manifest: dict) -> str:
    """The references' ZMP margins per phase (module docstring)."""
    phases = list(gu.phases("back"))
    head = f"{'clip':<18}{'start':<7}" + "".join(f"{p:>13}" for p in phases)
    lines = ["reference: smallest ZMP margin in the contacts' hull per phase, m (frames outside)", head, "-" * len(head)]
    for raw in raws:
        margin, spans = zmp_margin(raw), phase_frames(manifest[raw.name])
        cells = []
        for p in phases:
            if p not in spans:
                cells.append(f"{'':>13}")
                continue
            m = margin[slice(*spans[p])]
            cells.append(f"{np.nanmin(m):>+8.2f} ({int((m < 0).sum()):>2})")
        lines.append(f"{raw.name:<18}{manifest[raw.name]['start']:<7}" + "".join(cells))
    return "\n".join(lines)


def main(argv=None) -> list[dict]:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--motions", default="corpus:test/getup", help="a get-up corpus set (the manifest gives the phases)")
    p.add_argument("--checkpoint", help="an imitation policy: a .pt file, a run directory (its best.pt) or a "
                                        "shipped name (tracker); default: the zero residual")
    p.add_argument("--threshold", type=float, default=0.5, help="m of mean body distance that counts as lost")
    p.add_argument("--tempo-scale", type=float, default=1.0,
                   help="play every clip this much faster (its tempo times this, within getup.TEMPO_LIMITS): "
                        "what a quicker get-up family would ask")
    p.add_argument("--out", help="JSON file for the rows")
    args = p.parse_args(argv)
    spec, seed = C.parse_seed(args.motions)
    drawn = {"getup": gu.RANGES["getup"]["tempo"], "getup_quick": C.GETUP_QUICK_TEMPO}  # the families' tempos
    families = C.parse(spec)[1]
    if not set(families) <= set(drawn):
        raise SystemExit(f"--motions must name get-up clips only (e.g. corpus:test/getup), got {args.motions!r}")
    lo = min(drawn[f][0] for f in families) * args.tempo_scale
    hi = max(drawn[f][1] for f in families) * args.tempo_scale
    if not gu.TEMPO_LIMITS[0] <= lo <= hi <= gu.TEMPO_LIMITS[1]:  # refused before the clips are made
        raise SystemExit(f"--tempo-scale {args.tempo_scale}: the clips' tempos would be {lo:.2f}-{hi:.2f}, outside "
                         f"the {gu.TEMPO_LIMITS} getup() makes")
    raws, records = C.generate(spec, seed, progress=False)
    manifest = {r.name: r.params for r in records}
    if args.tempo_scale != 1.0:
        manifest = {name: {**params, "tempo": params["tempo"] * args.tempo_scale} for name, params in manifest.items()}
        raws = [gu.getup(**{k: manifest[r.name][k] for k in GETUP_ARGS}, name=r.name) for r in raws]
    lib = MotionLib(raws)
    if args.checkpoint:
        import agents
        from agents.recipes import find_checkpoint
        from smpl_envs.policy_settings import training_record, with_trained_settings

        model = agents.load(find_checkpoint(args.checkpoint))
        env_id, trained = training_record(model)
        if env_id != ENV_ID:
            raise SystemExit(f"{args.checkpoint} was trained on {env_id}, not {ENV_ID}")
        kwargs = with_trained_settings(ENV_ID, trained, {})
        act = lambda obs: model.predict(obs, deterministic=True)[0]  # noqa: E731
        title = f"{args.checkpoint} on {args.motions}"
    else:
        kwargs = {"action_mode": "residual"}
        act = lambda obs: np.zeros((len(obs), 69), np.float32)  # noqa: E731
        title = f"PD on the reference (zero residual) on {args.motions}"
    if args.tempo_scale != 1.0:
        title += f", {args.tempo_scale:g} times as fast"
    dist, facing = follow(lib, act, kwargs)
    rows = report(lib, manifest, dist, args.threshold, facing)
    print(table(rows, title + f" (lost: mean body distance > {args.threshold} m)"))
    print()
    print(zmp_table(raws, manifest))
    if args.out:
        with open(args.out, "w") as f:
            json.dump({"title": title, "threshold": args.threshold, "rows": rows}, f, indent=1)
    return rows


if __name__ == "__main__":
    main()
