"""Which learning-curve panels a run's log gets, and that a log renders to a PNG."""
import numpy as np
import pytest

from agents.plot import compared_columns, panels_for, plot_run, plot_runs, training_minutes


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


def test_minutes_add_up_over_a_resumed_run():
    # elapsed_s starts again at 0 when a run is resumed: the second segment continues the first.
    elapsed = np.array([60.0, 120.0, np.nan, 180.0, 30.0, 90.0, 15.0])
    np.testing.assert_allclose(training_minutes(elapsed)[[0, 1, 3, 4, 5, 6]], [1, 2, 3, 3.5, 4.5, 4.75])


def _run(root, name, rows):
    csv = root / name / "logs" / "progress.csv"
    csv.parent.mkdir(parents=True)
    csv.write_text("time/total_timesteps,time/elapsed_s,rollout/ep_len_mean,eval/no_fall,eval/trials_far\n"
                   + "".join(f"{t},{e},{n},{f},64\n" for t, e, n, f in rows))
    return root / name


def test_a_comparison_of_runs_renders_and_refuses_mistakes(tmp_path):
    a = _run(tmp_path, "pulse", [(2048, 30, 20, 0.1), (4096, 60, 40, 0.5)])
    b = _run(tmp_path, "scratch", [(4096, 30, 10, 0.0), (8192, 60, 12, "")])
    out = plot_runs([a, b], tmp_path / "cmp.png", labels=["PULSE", "scratch"], x="minutes")
    assert out.stat().st_size > 10_000
    with pytest.raises(ValueError, match="1 label"):
        plot_runs([a, b], tmp_path / "x.png", labels=["PULSE"])
    with pytest.raises(ValueError, match="at least two runs"):
        plot_runs([a], tmp_path / "x.png")
    with pytest.raises(ValueError, match="x must be one of"):
        plot_runs([a, b], tmp_path / "x.png", x="hours")
    from agents.cli import main

    assert main(["plot", str(a), str(b), "--out", str(tmp_path / "c.png"), "--label", "p", "--label", "s"]) == 0
    for argv in (["plot", str(a), str(b)], ["plot", str(a), "--x", "minutes"]):  # no --out; --x of one run
        with pytest.raises(SystemExit) as stop:
            main(argv)
        assert stop.value.code == 2


def test_a_comparison_draws_the_headline_columns_or_the_ones_asked_for(tmp_path):
    cols = _columns(eval__success_rate=[0, 1, 1, 1], eval__mpjpe_g=[80, 50, 40, 30], eval__all_mpjpe_g=[1, 1, 1, 1],
                    eval__clip_mean_accel=[1, 1, 1, 1], eval__score=[1, 1, 1, 1], rollout__ep_len_mean=[1, 2, 3, 4])
    assert compared_columns([cols]) == ["eval/success_rate", "eval/mpjpe_g", "rollout/ep_len_mean"]
    goal = _columns(eval__score=[0, 1, 1, 1], eval__no_fall=[0, 0, 1, 1], eval__trials_far=[64] * 4)
    assert compared_columns([goal]) == ["eval/no_fall", "eval/score"]
    a = _run(tmp_path, "a", [(2048, 30, 20, 0.1)])
    b = _run(tmp_path, "b", [(2048, 30, 20, 0.2)])
    assert plot_runs([a, b], tmp_path / "m.png", metrics=["no_fall"]).is_file()
    with pytest.raises(ValueError, match="no run logged 'speed_error'; evaluation columns: no_fall, trials_far"):
        plot_runs([a, b], tmp_path / "m.png", metrics=["speed_error"])


def test_stages_joined_with_commas_read_as_one_run(tmp_path):
    # A second stage started with --init counts its steps from 0 again: joined, its steps follow
    # the first stage's last one, its columns keep their rows, and minutes add up.
    from agents.plot import read_run

    first = _run(tmp_path, "stage1", [(2048, 30, 20, 0.1), (4096, 60, 40, 0.5)])
    second = _run(tmp_path, "stage2", [(1024, 20, 50, 0.6), (3072, 40, 60, 0.7)])
    columns, last = read_run(f"{first},{second}")
    np.testing.assert_array_equal(columns["time/total_timesteps"], [2048, 4096, 5120, 7168])
    np.testing.assert_array_equal(columns["eval/no_fall"], [0.1, 0.5, 0.6, 0.7])
    np.testing.assert_allclose(training_minutes(columns["time/elapsed_s"]), [0.5, 1.0, 4 / 3, 5 / 3])
    assert last == second / "logs" / "progress.csv"
    out = plot_run(f"{first},{second}")
    assert out == second / "curves.png" and out.stat().st_size > 10_000
    assert plot_runs([f"{first},{second}", first], tmp_path / "cmp.png").is_file()
    with pytest.raises(ValueError, match="an empty stage"):
        read_run(f"{first},")
    with pytest.raises(FileNotFoundError, match="no progress CSV"):
        read_run(f"{first},{tmp_path / 'missing'}")
