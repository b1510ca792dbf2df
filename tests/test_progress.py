"""Progress bars: tqdm's on a terminal, whole plain lines in a log (no carriage returns)."""
import io

import numpy as np
from tqdm import tqdm

from smpl_envs.progress import PlainProgress, pbar


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def test_a_log_gets_a_line_per_tenth_and_no_carriage_returns():
    log = io.StringIO()
    bar = pbar(total=1000, desc="PPO", unit="step", file=log, interval=1e9)
    assert isinstance(bar, PlainProgress)
    for _ in range(1000):
        bar.update(1)
        bar.set_postfix(ep_len="30", refresh=False)
    bar.close()
    text = log.getvalue()
    assert "\r" not in text
    lines = text.splitlines()
    assert len(lines) == 11, lines  # the start, then 10 %, 20 % ... 100 %
    assert lines[0].startswith("PPO:   0% 0/1000") and lines[-1].startswith("PPO: 100% 1000/1000")
    assert "ep_len=30" in lines[-1] and text.endswith("\n")


def test_without_a_total_the_interval_decides():
    quiet, chatty = io.StringIO(), io.StringIO()
    assert list(pbar(iter(range(5)), file=quiet, interval=1e9)) == list(range(5))
    assert len(quiet.getvalue().splitlines()) == 2  # start and end only
    list(pbar(iter(range(5)), file=chatty, interval=0.0))
    assert len(chatty.getvalue().splitlines()) == 6  # start and every item


def test_a_terminal_gets_tqdms_bar_and_disabled_bars_write_nothing():
    term = _Terminal()
    bar = pbar(total=3, file=term)
    assert type(bar) is tqdm
    bar.update(3)
    bar.close()
    assert "\r" in term.getvalue()
    log = io.StringIO()
    bar = pbar(total=3, file=log, disable=True)
    bar.update(3)
    bar.close()
    assert log.getvalue() == ""


def test_closing_after_the_last_line_does_not_repeat_it():
    log = io.StringIO()
    with pbar(total=4, file=log, interval=1e9) as bar:
        bar.update(4)
    assert log.getvalue().count("4/4") == 1


def test_an_evaluation_logs_plain_lines(capsys):
    import smpl_envs

    zero = lambda obs: np.zeros((len(obs), 69))  # noqa: E731  (falls within a second)
    smpl_envs.evaluate(zero, "SMPL/Imitation-v0", motions=["jump", "kick"], num_envs=2, progress=True)
    err = capsys.readouterr().err  # pytest's capture is not a terminal
    assert "\r" not in err and "evaluate: 100% 2/2" in err
