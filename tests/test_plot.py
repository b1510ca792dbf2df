"""Which learning-curve panels a run's log gets, and that a log renders to a PNG."""
import numpy as np

from agents.plot import panels_for, plot_run


def _columns(**series):
    x = np.arange(1, 5) * 1000.0
    return {"time/total_timesteps": x, **{k.replace("__", "/"): np.asarray(v, float) for k, v in series.items()}}


def _drawn(panels):
    return {key for p in panels for key, _ in p.left + p.right}


def test_imitation_eval_leaves_out_the_ranking_score():
    # Imitation logs `score` (success rate less 1e-6 x error) only to pick the best checkpoint.
    cols = _columns(eval__success_rate=[1, 1, 1, 1], eval__mpjpe_g=[80, 50, 40, 30], eval__score=[1, 1, 1, 1])
    panels = panels_for(cols)
    assert "eval/score" not in _drawn(panels)
    success = next(p for p in panels if any(k == "eval/success_rate" for k, _ in p.left))
    assert success.fraction and "eval/mpjpe_g" in {k for k, _ in success.right}


def test_goal_task_eval_draws_its_score():
    cols = _columns(eval__score=[0.2, 0.4, 0.5, 0.6], eval__no_fall=[0, 0.5, 1, 1], eval__speed_error=[2, 1, 1, 0.5])
    panels = panels_for(cols)
    task = next(p for p in panels if p.title == "Task evaluation")
    assert [k for k, _ in task.left] == ["eval/score", "eval/no_fall"]
    assert [k for k, _ in task.right] == ["eval/speed_error"]


def test_distillation_gets_its_losses_on_a_log_axis():
    cols = _columns(train__action_loss=[3e-3, 2e-3, 1e-3, 5e-4], train__kl=[1e-5, 1e-3, 1e-2, 5e-2],
                    train__kl_weight=[0.01, 0.01, 0.005, 0.001])
    distil = next(p for p in panels_for(cols) if p.title == "Distillation")
    assert distil.log and [k for k, _ in distil.left] == ["train/action_loss", "train/kl"]
    assert [k for k, _ in distil.right] == ["train/kl_weight"]  # encoder_std absent from this log
    assert not any(p.title == "Distillation" for p in panels_for(_columns(train__policy_loss=[1, 1, 1, 1])))


def test_a_short_log_renders(tmp_path):
    csv = tmp_path / "logs" / "progress.csv"
    csv.parent.mkdir()
    csv.write_text("time/total_timesteps,rollout/ep_len_mean,eval/success_rate,eval/mpjpe_g,eval/score\n"
                   "2048,20,,,\n4096,25,1.0,80.5,0.99992\n")
    out = plot_run(tmp_path)
    assert out == tmp_path / "curves.png" and out.stat().st_size > 10_000
