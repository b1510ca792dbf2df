"""Agents for smpl-envs (PPO, AMP, PMCP, PULSE): arrive with a later issue."""
