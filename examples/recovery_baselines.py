"""Policy-free baselines of `SMPL/Recovery-v0` through its evaluation protocol (PHC's Succ-5s and
Succ-10s for fallen, far (3 m) and fallen+far starts on the standing clip), printed as one table.

    python examples/recovery_baselines.py                      # 100 trials per start kind
    python examples/recovery_baselines.py --trials 1000 --out out/   # the paper's count (slow on a CPU)
    python examples/recovery_baselines.py --getup-guide corpus:getup   # and PD following a get-up

Policies: "zero, absolute" (PD targets 0: the body springs towards the T-pose), "zero, residual"
(PD targets = the reference pose: the PD controllers alone pull towards standing), and
"random, absolute" (uniform random actions). None of them walks, so far starts fail; what a
fallen start gets from the PD controllers alone is the interesting number. Writes
`recovery_<policy>.json` per policy under --out when given. With --getup-guide, one more row:
"zero, residual, guided", the PD controllers following a get-up clip shown to a body on the floor
(the `getup_guide` option, docs/tasks/recovery.md), what a tracker starts from there.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import smpl_envs
from smpl_envs.evaluation import evaluate

KINDS = ("fallen", "far", "fallen+far")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--trials", type=int, default=100, help="trials per start kind (the protocol's default is 1000)")
    p.add_argument("--num-envs", type=int, default=16, help="worlds stepped together")
    p.add_argument("--fallen-cache-size", type=int, default=128, help="fallen states to draw from")
    p.add_argument("--out", type=Path, default=None, help="directory for the JSON results")
    p.add_argument("--getup-guide", default=None, help="get-up clips for the guided row (e.g. corpus:getup)")
    args = p.parse_args()
    rng = np.random.default_rng(0)
    zero = lambda obs: np.zeros((len(obs), 69), np.float32)  # noqa: E731
    policies = {
        "zero, absolute": (zero, {"action_mode": "absolute"}),
        "zero, residual": (zero, {"action_mode": "residual"}),
        "random, absolute": (lambda obs: rng.uniform(-1, 1, (len(obs), 69)).astype(np.float32), {"action_mode": "absolute"}),
    }
    if args.getup_guide:
        policies["zero, residual, guided"] = (zero, {"action_mode": "residual", "getup_guide": args.getup_guide})
    lines = [f"{'policy':<24}" + "".join(f"{k + ' 5s':>16}{k + ' 10s':>17}" for k in KINDS)]
    for label, (policy, kwargs) in policies.items():
        result = evaluate(policy, "SMPL/Recovery-v0", num_envs=args.num_envs, progress=False, trials=args.trials,
                          env_kwargs={**kwargs, "fallen_cache_size": args.fallen_cache_size})
        s = result.summary
        lines.append(f"{label:<24}" + "".join(f"{100 * s[f'succ_5s_{k}']:>15.1f}%{100 * s[f'succ_10s_{k}']:>16.1f}%"
                                              for k in KINDS))
        if args.out is not None:
            result.save(args.out / f"recovery_{label.replace(', ', '_')}.json")
    print(f"Succ-5s / Succ-10s, {args.trials} trials per start kind "
          f"(success: back within 0.5 m mean body distance by 5 s / 10 s, staying so to the end of an 11-s trial)")
    print("\n".join(lines))


if __name__ == "__main__":
    print(f"smpl_envs {smpl_envs.__version__}")
    main()
