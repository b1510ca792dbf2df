"""SimPoE's policy (Yuan et al. 2021) for `SMPL/VideoPose-v0`: a kinematic refinement unit in
front of a residual actor-critic, trained jointly with PPO (`SimPoEPPO`, PPO with an optional
supervised pretraining of the unit).

    PPO-like:  SimPoEPPO("SMPL/VideoPose-v0", policy="KinematicRefinement", refine_pretrain_samples=20_000)
    recipe:    tasks/videopose_ppo.yaml

The refinement unit (`agents.refinement.RefinementUnit`) reads, from the observation, the next frame's kinematic
estimate (root position and rotation in the heading frame, 69 joint angles), the 2D keypoints with
their confidences and the camera, and updates the joint angles `iterations` times (SimPoE: 5):

1. forward kinematics of the current angles gives the 3D joints X (heading frame, the
   humanoid's root frame up to its yaw: what the observation's positions are in);
2. the confidence-weighted reprojection loss L = sum_j c_j ||proj(X_j) - x_j||^2 (normalised
   image coordinates) and its gradient dL/dX (analytic: the pinhole Jacobian, `smpl_envs.camera`);
3. the update: a Gauss-Newton step on the angles, dL/dX carried to each hinge through the
   kinematic chain (dL/dtheta = axis . sum over the hinge's subtree of (X_j - X_hinge) x dL/dX_j)
   and scaled by the diagonal of the Gauss-Newton matrix, times a learnt step size, plus a
   learnt correction from an MLP of (angles, X, dL/dX, that step, confidences), whose last layer
   starts at zero. The unit therefore starts as damped Gauss-Newton on the reprojection loss
   (it lowers the loss before any training: a test checks it) and learns what the keypoints
   cannot say (depth, occluded joints) from supervised regression and from PPO.

The actor sees the (normalised) observation, the refined angles and the refined pose's dL/dX, and
outputs a residual on top of the refined pose (SimPoE's residual angle connection). With
`refined_reference` (the recipe's setting) the observation's imitation goal is first re-posed on
the refined pose, so the actor tracks what the unit made of the estimate, as SimPoE's control unit
reads features of the refined pose; without it the goal is the estimate's. Its action
mean is (refined - estimated angles) / (residual_scale x range) + MLP(...) in the env's residual
action units, and any meta-PD or root-force actions the env has (an MLP output each). Gradients of
PPO's loss flow through the mean into the unit: refinement and control are trained together.
With `iterations=0` the policy is the same actor-critic on the unrefined estimate (the
"no refinement" ablation).

Observation normalisation: the columns the unit reads (estimate root and angles, keypoints,
confidences, camera) pass through `normalize` raw, so the rollout's stored observations still hold
them; the rest is normalised with running statistics, as `ActorCritic` does. The actor and the
critic read every column normalised (`features`).

Warm start from the tracker (`init_from`, `agent.init: tracker` in the recipe): VideoPose-v0's
observation begins with Imitation-v0's (the estimate as the reference), and its residual actions
mean what the tracker's mean, so the tracker's actor and critic become this policy's, with zero
weight on the inputs the tracker never had and zero outputs for meta-PD and the root force. At
step 0 the policy then acts exactly as the tracker following the estimate (plus the refinement's
offset): it starts out balancing instead of learning to stand from nothing, which the suite's
from-scratch run had not begun to do after 1.4M samples (docs/tasks/videopose.md). SimPoE trains
from scratch with far more samples; this is PHC's reuse of the imitator.
"""
from __future__ import annotations

import dataclasses
from typing import Sequence

import gymnasium as gym
import numpy as np
import torch
from torch import nn
from torch.distributions import Normal

from smpl_envs.features import SELF_OBS_LAYOUT, layout_slices
from smpl_envs.humanoid.skeleton import ACTION_SCALE, NUM_BODIES, NUM_HINGES
from smpl_envs.video_features import VIDEO_TASK_LAYOUT

from .networks import Policy, ValueCritic, _sizes, mlp
from .normalizer import RunningNorm
from .policies import register_policy
from .ppo import PPO, PPOConfig
from .refinement import GRAD_FEATURE_SCALE, Refinement, RefinementUnit, rot6d_to_matrix
from .rollout import InfoColumn, RolloutBuffer, RolloutHooks

OBS = layout_slices({"self": SELF_OBS_LAYOUT, **VIDEO_TASK_LAYOUT})
OBS_DIM = max(s.stop for s in OBS.values())
# The columns the refinement reads (kept raw by `normalize`).
RAW_COLUMNS = ("estimate/ref_pos", "estimate/ref_rot", "video/est_dof", "video/keypoints", "video/confidence",
               "video/camera_rot", "video/camera_pos")
# With `refined_reference`, also the estimate's differences from the simulated bodies: the actor's
# reference is re-posed from them.
REFERENCE_COLUMNS = ("estimate/diff_pos", "estimate/diff_rot")
ROOT_COLUMNS = ("self/root_height",)  # with `refine_root`: where the floor is
# Imitation-v0's observation: the first columns of VideoPose-v0's (its own state, the estimate as the
# reference); what a warm start from an imitation policy maps onto.
IMITATION_OBS = slice(0, OBS["estimate/ref_rot"].stop)
def split_observation(obs: torch.Tensor, floor: bool = False) -> dict[str, torch.Tensor]:
    """The refinement's inputs from raw VideoPose-v0 observations (B, 1087); `floor`: with the
    floor's height relative to the simulated pelvis, for a unit that refines the root."""
    b = len(obs)
    parts = {"root_pos": obs[:, OBS["estimate/ref_pos"]][:, :3],
             "root_rot": rot6d_to_matrix(obs[:, OBS["estimate/ref_rot"]][:, :6]),
             "angles": obs[:, OBS["video/est_dof"]],
             "keypoints": obs[:, OBS["video/keypoints"]].reshape(b, NUM_BODIES, 2),
             "confidence": obs[:, OBS["video/confidence"]],
             "cam_rot": obs[:, OBS["video/camera_rot"]].reshape(b, 3, 3),
             "cam_pos": obs[:, OBS["video/camera_pos"]]}
    if floor:
        parts["floor"] = -obs[:, OBS["self/root_height"]][:, 0]
    return parts


@register_policy
class KinematicRefinement(ValueCritic, Policy):
    """SimPoE's policy for `SMPL/VideoPose-v0` (module docstring).

    Args (after the spaces): iterations (refinement updates; SimPoE: 5; 0: none), refine_hidden
    (the unit's correction MLP), actor_hidden, critic_hidden, activation, log_std_init,
    learn_std, obs_clip, normalize_value, residual_scale (the env's: refined angles become
    residual actions with it), refined_reference, refine_root.

    `refined_reference`: the actor reads Imitation-v0's goal towards the refined pose instead of
    the estimate (`reference_on`), as SimPoE's control unit computes its features from the refined
    kinematic pose; a warm-started tracker then follows the refined pose with the weights it
    learnt, rather than being shown the estimate while its targets are the refinement's. The
    goal's velocity terms stay the estimate's (one frame gives no refined velocity). Off by
    default: the policies trained before it (the shipped `videopose`) read the estimate.

    `refine_root`: the unit also corrects the estimate's root position (one learnt update after
    the angles', from the refined pose's heights above the floor and the reprojection gradient):
    the estimate sinks into the floor and drifts along the camera ray, and the tracker falls more
    often on the true joint angles with the estimate's root than with the true root (29.7 against
    39.1 % without a fall, docs/tasks/videopose.md). The refined root moves the actor's goal
    (with `refined_reference`); the PD targets are joint angles and do not depend on it. Off by
    default, as `refined_reference`.
    """

    def __init__(self, obs_dim: int, action_space: gym.spaces.Box | int, *, iterations: int = 5,
                 refine_hidden: Sequence[int] = (256, 256), actor_hidden: Sequence[int] = (512, 256),
                 critic_hidden: Sequence[int] = (512, 256), activation: str = "silu", log_std_init: float = -2.9,
                 learn_std: bool = False, obs_clip: float | None = 5.0, normalize_value: bool = True,
                 residual_scale: float = 0.25, refined_reference: bool = False, refine_root: bool = False):
        super().__init__(obs_dim, action_space)
        if self.obs_dim != OBS_DIM:
            raise ValueError(f"KinematicRefinement reads SMPL/VideoPose-v0's observation ({OBS_DIM} numbers), "
                             f"got {self.obs_dim}")
        if self.act_dim < NUM_HINGES:
            raise ValueError(f"KinematicRefinement needs the 69 residual PD targets first; the env acts with {self.act_dim}")
        if isinstance(iterations, bool) or not isinstance(iterations, int) or iterations < 0:
            raise ValueError(f"iterations must be an integer >= 0, got {iterations!r}")
        self.iterations = iterations
        self.refined_reference, self.refine_root = bool(refined_reference), bool(refine_root)
        self.obs_norm = RunningNorm(obs_dim, clip=obs_clip)
        raw = torch.zeros(obs_dim, dtype=torch.bool)
        for name in (RAW_COLUMNS + (REFERENCE_COLUMNS if self.refined_reference else ())
                     + (ROOT_COLUMNS if self.refine_root else ())):
            raw[OBS[name]] = True
        self.register_buffer("_raw", raw, persistent=False)
        self.refine = RefinementUnit(iterations, refine_hidden, activation, root=self.refine_root)
        self.value_norm = RunningNorm((), clip=None) if normalize_value else None
        actor_in = obs_dim + NUM_HINGES + 3 * NUM_BODIES
        self.actor = mlp(actor_in, _sizes("actor_hidden", actor_hidden), self.act_dim, activation, out_gain=0.01)
        self.critic = mlp(obs_dim, _sizes("critic_hidden", critic_hidden), 1, activation, out_gain=1.0)
        self.log_std = nn.Parameter(torch.full((self.act_dim,), float(log_std_init)), requires_grad=bool(learn_std))
        self.register_buffer("_residual_unit", torch.as_tensor(float(residual_scale) * ACTION_SCALE, dtype=torch.float32),
                             persistent=False)

    # --- observations: the refinement's columns stay raw
    def normalize(self, obs: torch.Tensor) -> torch.Tensor:
        return torch.where(self._raw, obs, self.obs_norm(obs))

    def update_obs_stats(self, obs: torch.Tensor) -> None:
        self.obs_norm.update(obs)

    def features(self, nobs: torch.Tensor) -> torch.Tensor:
        """Every column normalised: what the actor and the critic read (the raw ones too)."""
        return torch.where(self._raw, self.obs_norm(nobs), nobs)

    def critic_input(self, nobs: torch.Tensor) -> torch.Tensor:
        return self.features(nobs)

    def refined(self, nobs: torch.Tensor):
        """(refined angles (B, 69), estimated angles (B, 69), dL/dX (B, 24, 3), loss before,
        loss after) of `normalize`d (or raw) observations."""
        r = self.refinement(nobs)
        return r.angles, nobs[:, OBS["video/est_dof"]], r.grad, r.loss_before, r.loss_after

    def refinement(self, nobs: torch.Tensor) -> Refinement:
        """The unit's `Refinement` of `normalize`d (or raw) observations."""
        return self.refine(**split_observation(nobs, floor=self.refine_root))

    def reference_on(self, nobs: torch.Tensor, r: Refinement) -> torch.Tensor:
        """`nobs` with its estimate block (Imitation-v0's goal) re-posed on the refinement `r`:
        every body moved by (refined - estimated) position and turned by R_refined R_estimated^T,
        all in the heading frame, so the positions, rotations and their differences from the
        simulated bodies are those of the refined pose (the columns must be raw: REFERENCE_COLUMNS)."""
        b = len(nobs)
        move = (r.pos - r.est_pos).reshape(b, -1)
        turn = r.rot @ r.est_rot.swapaxes(-1, -2)
        out = nobs.clone()
        for name in ("estimate/diff_pos", "estimate/ref_pos"):
            out[:, OBS[name]] = nobs[:, OBS[name]] + move
        for name in ("estimate/diff_rot", "estimate/ref_rot"):
            m = rot6d_to_matrix(nobs[:, OBS[name]].reshape(b, NUM_BODIES, 6))
            out[:, OBS[name]] = (turn @ m)[..., :, :2].reshape(b, -1)
        return out

    def distribution(self, nobs: torch.Tensor) -> Normal:
        return self.scored_distribution(nobs)[0]

    def scored_distribution(self, nobs: torch.Tensor) -> tuple[Normal, dict[str, torch.Tensor]]:
        """The action distribution, with the refined angles (B, 69) it is centred on as
        `extras["refined_angles"]` (and the refined root (B, 3) as `extras["refined_root"]` with
        `refine_root`): the refinement's supervised loss reuses this forward pass. `extras["offset"]`
        (B, act_dim): the part of the mean that is the refinement's offset (zero beyond the 69)."""
        r = self.refinement(nobs)
        angles, est, grad = r.angles, nobs[:, OBS["video/est_dof"]], r.grad
        seen = self.reference_on(nobs, r) if self.refined_reference else nobs
        feat = torch.cat([self.features(seen), angles, GRAD_FEATURE_SCALE * grad.reshape(len(nobs), -1)], -1)
        mu = self.actor(feat)
        offset = (angles - est) / self._residual_unit
        mu = torch.cat([mu[:, :NUM_HINGES] + offset, mu[:, NUM_HINGES:]], -1)
        extras = {"refined_angles": angles, "offset": torch.cat([offset, torch.zeros_like(mu[:, NUM_HINGES:])], -1),
                  **({"refined_root": r.root} if self.refine_root else {})}
        return Normal(mu, self.log_std.exp().expand_as(mu), validate_args=False), extras

    def action_distribution(self, nobs: torch.Tensor) -> Normal:
        return self.distribution(nobs)

    def forward(self, nobs: torch.Tensor):
        return self.distribution(nobs), self.value(nobs)

    def action_std(self) -> torch.Tensor:
        return self.log_std.detach().exp()

    # --- warm start (agents.warm_start)
    @torch.no_grad()
    def init_from(self, source_class: type, state: dict, exclude: Sequence[str] = ()) -> tuple[list[str], list[str]]:
        """Start from an imitation `ActorCritic` (module docstring), its layer sizes and activation
        this policy's. Returns (copied, kept) names of this policy's state dict; a ValueError says
        what does not fit."""
        from .policies import ActorCritic

        if source_class is not ActorCritic:
            raise ValueError(f"KinematicRefinement starts from an imitation ActorCritic (the tracker), not a "
                             f"{source_class.__name__}")
        n = IMITATION_OBS.stop
        if tuple(state["obs_norm.mean"].shape) != (n,):
            raise ValueError(f"the source policy reads {tuple(state['obs_norm.mean'].shape)[0]} observation numbers; "
                             f"an SMPL/Imitation-v0 policy in rotation form reads {n}")
        skip = lambda name: any(name.startswith(p) for p in exclude)  # noqa: E731
        copied = []
        for net in ("actor", "critic"):
            if skip(net + "."):
                continue
            layers = [i for i, m in enumerate(getattr(self, net)) if isinstance(m, nn.Linear)]
            for k, i in enumerate(layers):
                w, b = state[f"{net}.{i}.weight"].float(), state[f"{net}.{i}.bias"].float()
                lin = getattr(self, net)[i]
                last = k == len(layers) - 1
                # the last layer's first rows: the 69 residual targets (the critic: its value)
                rows = w.shape[0] if last else lin.out_features
                cols = n if k == 0 else lin.in_features
                if w.shape[1] != cols or w.shape[0] != rows or rows > lin.out_features:
                    raise ValueError(f"{net} layer {k} is {tuple(w.shape)} in the source, this policy's is "
                                     f"{tuple(lin.weight.shape)}: make {net}_hidden the source's")
                lin.weight.zero_()
                lin.bias.zero_()
                lin.weight[:rows, :cols] = w[:rows]
                lin.bias[:rows] = b[:rows]
                copied += [f"{net}.{i}.weight", f"{net}.{i}.bias"]
        if not skip("obs_norm"):
            self.obs_norm.mean[:n] = state["obs_norm.mean"]
            self.obs_norm.var[:n] = state["obs_norm.var"]
            self.obs_norm.count.copy_(state["obs_norm.count"])
            copied += ["obs_norm.mean", "obs_norm.var", "obs_norm.count"]
        if self.value_norm is not None and "value_norm.mean" in state and not skip("value_norm"):
            for k in ("mean", "var", "count"):
                getattr(self.value_norm, k).copy_(state[f"value_norm.{k}"])
                copied.append(f"value_norm.{k}")
        if not skip("log_std"):
            self.log_std[:NUM_HINGES] = state["log_std"][:NUM_HINGES]
            copied.append("log_std")
        return copied, [k for k in self.state_dict() if k not in copied]

    # --- supervised regression of the refinement
    def refinement_error(self, obs: torch.Tensor, truth_angles: torch.Tensor,
                         angles: torch.Tensor | None = None) -> torch.Tensor:
        """(B,) mean squared distance (m^2) over the 24 bodies between the refined pose and the
        true one, both posed by forward kinematics from the estimate's root. `angles`: the
        refined angles when the caller has them already."""
        if angles is None:
            angles = self.refinement(obs).angles
        return self.body_error(obs, angles, truth_angles)

    def body_error(self, obs: torch.Tensor, angles: torch.Tensor, truth_angles: torch.Tensor) -> torch.Tensor:
        """(B,) mean squared distance (m^2) over the 24 bodies between the poses of `angles` and
        of `truth_angles`, both posed by forward kinematics from the estimate's root in `obs`."""
        parts = split_observation(obs)
        fk = self.refine.forward_kinematics
        pos = fk(parts["root_pos"], parts["root_rot"], angles)[0]
        true = fk(parts["root_pos"], parts["root_rot"], truth_angles)[0]
        return (pos - true).square().sum(-1).mean(-1)

    def refinement_angle_error(self, obs: torch.Tensor, truth_angles: torch.Tensor,
                               angles: torch.Tensor | None = None) -> torch.Tensor:
        """(B,) mean squared difference (rad^2, wrapped to [-pi, pi)) over the 69 hinges between
        the refined joint angles and the true ones. `angles`: as in `refinement_error`."""
        if angles is None:
            angles = self.refinement(obs).angles
        d = torch.remainder(angles - truth_angles + np.pi, 2 * np.pi) - np.pi
        return d.square().mean(-1)

    def refinement_root_error(self, obs: torch.Tensor, truth_root: torch.Tensor,
                              root: torch.Tensor | None = None) -> torch.Tensor:
        """(B,) squared distance (m^2) between the refined root position (the estimate's without
        `refine_root`) and the true one (`info["next_truth_root_pos"]`, the same frame). `root`: the
        refined root when the caller has it already."""
        if root is None:
            root = self.refinement(obs).root
        return (root - truth_root).square().sum(-1)


# ---------------------------------------------------------------------------------------- training
TRUTH = "next_truth_dof_pos"  # info: the true joint angles of the frame each observation previews
TRUTH_ROOT = "next_truth_root_pos"  # and its true root position (the observation's frame)
# The refinement's supervised losses: (policy method, unit of its root mean square).
REFINE_TARGETS = {"angles": ("refinement_angle_error", "deg"), "positions": ("refinement_error", "mm")}
# Each supervised error's scale from its squared unit (rad^2, m^2) to what its root mean square is logged in.
REFINE_UNITS = {"deg": 180.0 / np.pi, "mm": 1000.0, "root_mm": 1000.0}


@dataclasses.dataclass
class SimPoEPPOConfig(PPOConfig):
    """PPO's hyperparameters and the refinement's supervised pretraining."""

    refine_pretrain_samples: int = 0
    """(observation, true pose) pairs gathered before the first update to regress the refinement
    unit on (0: no pretraining); they come from stepping the env with the PD tracking of the
    estimate, and need an env with ground truth (generated input)"""
    refine_pretrain_epochs: int = 20
    """passes over those pairs"""
    refine_pretrain_lr: float = 1e-3
    """Adam step size of the pretraining"""
    refine_target: str = "angles"
    """what the refinement's supervised loss (pretraining and `refine_aux_coef`) regresses:
    "angles", the true joint angles (`refinement_angle_error`, rad^2), or "positions", the true
    body positions (`refinement_error`, m^2). Positions leave a limb's twist free (it moves no
    joint), and the tracker falls more on such a refinement than on none: measured at step 0
    (corpus:test, 184 sequences), 4.9 % without a fall after position pretraining, 12.0 % with the
    untrained unit and 18.5 % after angle pretraining (docs/tasks/videopose.md)"""
    refine_aux_coef: float = 0.0
    """weight of the refinement's supervised loss in every PPO minibatch, on the true pose the
    env reports with each observation (0: PPO's loss alone); needs an env with ground truth.
    Why: PPO's gradient alone undoes the pretraining (measured, positions: 28 mm rms body error
    after it, 62 mm after 5M steps of joint training, 36 mm with this at 1000 after 0.85M)"""

    bounds_on_refinement: bool = True
    """the bounds loss on the whole action mean, the refinement's offset included (True: PPO's
    way, as the policies before 2026-12-06 trained), or on the actor's own part only (False). Where
    the refined angles leave the residual range (0.2 % of the action numbers at step 0, but far:
    a bounds loss of 0.5 a sample, against 0.0002-0.0006 on the actor's part) the env clips the
    action anyway, and on the whole mean the loss's gradient (x bounds_loss_coef) pulls the
    refinement back towards the estimate"""

    refine_lr_scale: float = 1.0
    """the refinement unit's learning rate in PPO as a factor on `learning_rate` (0: fixed after
    its pretraining). The refined angles are the action mean's offset, and with PHC's action std
    (0.055) a shift of 0.01 in every action number is a KL of about 1: at 1 the refinement's own
    steps leave most of PPO's samples outside its clip range (its supervised loss alone, in the
    critic warm-up: approx. KL 0.80, 64 % clipped), at 0.1 far fewer (0.027, 25 %). Measured no
    better for it over 0.5M steps (docs/tasks/videopose.md), so 1 stays the recipe's"""

    def __post_init__(self) -> None:
        super().__post_init__()
        if not self.refine_lr_scale >= 0:
            raise ValueError(f"refine_lr_scale must be >= 0, got {self.refine_lr_scale!r}")
        for name in ("refine_pretrain_samples", "refine_pretrain_epochs"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise ValueError(f"{name} must be an integer >= 0, got {v!r}")
        if not self.refine_aux_coef >= 0:
            raise ValueError(f"refine_aux_coef must be >= 0, got {self.refine_aux_coef!r}")
        if self.refine_target not in REFINE_TARGETS:
            raise ValueError(f"refine_target must be one of {', '.join(REFINE_TARGETS)}, got {self.refine_target!r}")


class SimPoEPPO(PPO):
    """PPO whose policy is SimPoE's (`KinematicRefinement`, the default), with the refinement
    unit optionally pretrained by supervised regression (`refine_pretrain_samples`) once, before
    the first update; then refinement and control train jointly through PPO's loss."""

    config_class = SimPoEPPOConfig
    default_policy = KinematicRefinement

    def __init__(self, *args, **kwargs):
        self.refine_pretrained = False
        super().__init__(*args, **kwargs)

    def _param_groups(self) -> list[dict]:
        trainable = [(n.startswith("refine."), p) for n, p in self.policy.named_parameters() if p.requires_grad]
        unit = [p for refine, p in trainable if refine]
        if self.config.refine_lr_scale == 1.0 or not unit:  # nothing to scale (no unit: iterations 0)
            return super()._param_groups()
        return [{"params": [p for refine, p in trainable if not refine], "lr_scale": 1.0},
                {"params": unit, "lr_scale": self.config.refine_lr_scale}]

    def learn(self, total_timesteps: int, *args, **kwargs):
        if self.config.refine_pretrain_samples and not self.refine_pretrained:
            self.pretrain_refinement(self.config.refine_pretrain_samples)
        return super().learn(total_timesteps, *args, **kwargs)

    def pretrain_refinement(self, samples: int) -> dict[str, float]:
        """Regress the refinement unit on `samples` (observation, true next pose) pairs of the
        attached env, on `refine_target`'s loss. Returns (and logs) the root mean square body
        error (mm) and joint-angle error (deg) before and after."""
        pol, env, cfg = self.policy, self.env, self.config
        if not isinstance(pol, KinematicRefinement):
            raise ValueError(f"refine_pretrain_samples needs the KinematicRefinement policy, not {type(pol).__name__}")
        if pol.iterations == 0:
            raise ValueError("refine_pretrain_samples needs a refinement unit (iterations >= 1); set it to 0")
        obs, truth = self._pretraining_pairs(env, samples)
        params = [p for p in pol.refine.parameters() if p.requires_grad]
        opt = torch.optim.Adam(params, lr=cfg.refine_pretrain_lr)
        data = {"obs": obs, "truth": truth}
        # A data-parallel job: every rank starts from rank 0's weights and steps on the ranks'
        # averaged gradients, so the unit stays one unit (in one process both are no-ops).
        self._replicate()
        sync = self._gradient_sync(pol.refine, opt)

        def rms() -> dict[str, float]:
            out = {}
            with torch.no_grad():
                for i in range(0, len(obs), 4096):
                    r = pol.refinement(obs[i:i + 4096])
                    for name, err in self._refinement_errors(obs[i:i + 4096], truth[i:i + 4096], r.angles, r.root,
                                                             every=True).items():
                        out.setdefault(name, []).append(err)
            return {unit: float(torch.cat(errs).mean().sqrt() * REFINE_UNITS[unit]) for unit, errs in out.items()}

        before = rms()
        from .rollout import torch_threads

        def loss_of(x, y):
            r = pol.refinement(x)
            return sum(self._refinement_errors(x, y, r.angles, r.root).values()).mean()

        with torch_threads(self.update_threads):
            for _ in range(cfg.refine_pretrain_epochs):
                for mb in self._minibatches(data, cfg.batch_size):
                    loss = sync.loss(lambda: loss_of(mb["obs"], mb["truth"]))
                    opt.zero_grad(set_to_none=True)
                    sync.backward(loss)
                    torch.nn.utils.clip_grad_norm_(params, cfg.max_grad_norm)
                    opt.step()
        after = rms()
        self.refine_pretrained = True
        for unit in before:
            self.logger.record(f"pretrain/refine_rms_{unit}_before", before[unit])
            self.logger.record(f"pretrain/refine_rms_{unit}_after", after[unit])
        if self.verbose and self.data_parallel.main:
            root = (f", {before['root_mm']:.1f} -> {after['root_mm']:.1f} mm rms root error" if "root_mm" in after else "")
            print(f"refinement pretraining on {len(obs)} frames ({cfg.refine_target}): {before['mm']:.1f} -> "
                  f"{after['mm']:.1f} mm rms body error, {before['deg']:.1f} -> {after['deg']:.1f} deg rms joint angle "
                  f"error{root}")
        self._collector = None  # the pairs came from stepping the env: the first rollout resets it
        return {f"{when}_{unit}": value for when, errs in (("before", before), ("after", after))
                for unit, value in errs.items()}

    @torch.no_grad()
    def _pretraining_pairs(self, env, samples: int) -> tuple[torch.Tensor, torch.Tensor]:
        obs, info = env.reset(seed=self.config.seed)
        keys = self._truth_keys()
        if any(k not in info for k in keys):
            raise ValueError(f"refine_pretrain_samples needs ground truth (info[{keys[-1]!r}]): train on "
                             "generated input (motions=), not on estimator files")
        zero = env.unwrapped.reference_action() if hasattr(env.unwrapped, "reference_action") else None
        if zero is None:
            zero = np.zeros((env.num_envs, env.single_action_space.shape[0]), np.float32)
        xs, ys, n = [], [], 0
        while n < samples:
            xs.append(torch.as_tensor(np.asarray(obs), dtype=torch.float32))
            ys.append(torch.cat([torch.as_tensor(np.asarray(info[k]), dtype=torch.float32) for k in keys], -1))
            n += len(xs[-1])
            obs, _, _, _, info = env.step(zero)  # PD tracking of the estimate; ended worlds autoreset
        return torch.cat(xs)[:samples].to(self.device), torch.cat(ys)[:samples].to(self.device)

    # --- the refinement's supervised loss during PPO (refine_aux_coef)
    def _rollout_hooks(self) -> RolloutHooks:
        if self.config.refine_aux_coef <= 0:
            return super()._rollout_hooks()
        keys = self._truth_keys()
        return InfoColumn(TRUTH, NUM_HINGES + 3 * (len(keys) - 1), self.device, carry=True, sources=keys, missing=(
            f"refine_aux_coef needs ground truth (info[{keys[-1]!r}]): train on generated input (motions=), "
            "not on estimator files, or set refine_aux_coef=0"))

    def _truth_keys(self) -> tuple[str, ...]:
        """The info keys of the truth the refinement regresses: the joint angles, and the root's place
        for a unit that refines it (side by side, (B, 69 [+ 3]))."""
        return (TRUTH, TRUTH_ROOT) if getattr(self.policy, "refine_root", False) else (TRUTH,)

    def _refinement_errors(self, obs, truth, angles, root, every: bool = False) -> dict[str, torch.Tensor]:
        """{unit: (B,) squared error} of a refinement (`angles`, `root`) against `truth` (`_truth_keys`'
        columns): `refine_target`'s (or, `every`, both targets'), and the root's with `refine_root`."""
        pol = self.policy
        targets = REFINE_TARGETS.values() if every else [REFINE_TARGETS[self.config.refine_target]]
        out = {unit: getattr(pol, method)(obs, truth[:, :NUM_HINGES], angles) for method, unit in targets}
        if pol.refine_root:
            out["root_mm"] = pol.refinement_root_error(obs, truth[:, NUM_HINGES:], root)
        return out

    def _loss(self, mb: dict[str, torch.Tensor]) -> tuple[torch.Tensor, ...]:
        coef = self.config.refine_aux_coef
        ev = self.policy.evaluate_actions(mb["obs"], mb["actions"])
        if not self.config.bounds_on_refinement and ev.extras and "offset" in ev.extras:
            ev = ev._replace(mean=ev.mean - ev.extras["offset"])  # the mean serves the bounds loss only
        terms = self._ppo_loss(mb, ev)
        if coef <= 0 or self.policy.iterations == 0:
            return terms
        # The stored observations are normalised except the refinement's columns (kept raw).
        errors = self._refinement_errors(mb["obs"], mb[TRUTH], ev.extras["refined_angles"], ev.extras.get("refined_root"))
        errors = {unit: e.mean() for unit, e in errors.items()}
        for unit, e in errors.items():
            self._refine_errors.setdefault(unit, []).append(float(e.detach()))
        return (terms[0] + coef * sum(errors.values()), *terms[1:])

    def _update(self, buf: RolloutBuffer) -> None:
        self._refine_errors: dict[str, list[float]] = {}
        super()._update(buf)
        for unit, errs in self._refine_errors.items():
            self.logger.record(f"train/refine_rms_{unit}", float(np.sqrt(np.mean(errs)) * REFINE_UNITS[unit]))

    def _extra_state(self) -> dict:
        return {"refine_pretrained": self.refine_pretrained}

    def _load_extra_state(self, state: dict) -> None:
        self.refine_pretrained = bool(state.get("refine_pretrained", False))


__all__ = ["KinematicRefinement", "Refinement", "RefinementUnit", "SimPoEPPO", "SimPoEPPOConfig", "split_observation",
           "rot6d_to_matrix"]
