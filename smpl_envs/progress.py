"""Progress bars that stay readable in a log file.

On a terminal (or in a notebook) `pbar` is tqdm's bar. Where the stream is not a terminal (a
file, a pipe, a cluster scheduler's log) tqdm's carriage-return redraws pile up into one huge
line, so there the bar is `PlainProgress`: the same tqdm object and API, which writes a whole line
at its start, at every tenth of the total, at least every `interval` seconds while it moves, and
at its end.

    for path in pbar(paths, desc="Loading motions", unit="file", disable=not show):
        ...
    bar = pbar(total=steps, unit="step", desc="PPO")   # bar.update(n), bar.set_postfix(...), bar.close()
"""
from __future__ import annotations

import math
import sys

from tqdm import tqdm as _std_tqdm
from tqdm.auto import notebook_tqdm as _notebook_tqdm, tqdm as _auto_tqdm

PLAIN_INTERVAL = 30.0  # seconds between plain lines while a bar moves slowly (a 10 % step comes sooner)


class PlainProgress(_std_tqdm):
    """tqdm writing plain lines: the start, each 10 % of `total`, at least every `interval`
    seconds of progress, and the end. Without a total only the interval and the end apply."""

    def __init__(self, *args, interval: float = PLAIN_INTERVAL, **kwargs):
        self._interval, self._last_line_t, self._last_mark, self._printed_n = float(interval), None, None, None
        # tqdm may then call display() on every update; display() decides whether a line is due.
        kwargs.update(mininterval=0, miniters=1, dynamic_ncols=False)
        iterable = args[0] if args else kwargs.get("iterable")
        total = kwargs.get("total", len(iterable) if hasattr(iterable, "__len__") else None)
        if kwargs.get("desc"):
            kwargs["desc"] = f"{kwargs['desc']}: "
        # No bar drawing: "PPO:  50% 20000/40000 [00:30<00:30, 650.2step/s, ep_len=30]"
        kwargs.setdefault("bar_format", "{desc}{percentage:3.0f}% {n_fmt}/{total_fmt} [{elapsed}<{remaining}, "
                                        "{rate_fmt}{postfix}]" if total else "{desc}{n_fmt} [{elapsed}, {rate_fmt}{postfix}]")
        super().__init__(*args, **kwargs)

    def _mark(self):
        return math.floor(10 * self.n / self.total) if self.total else None

    def display(self, msg=None, pos=None):
        if msg is not None:  # tqdm clearing its line (leave=False): a log has nothing to clear
            return False
        now = self._time()
        due = (self._last_line_t is None or self._mark() != self._last_mark
               or (now - self._last_line_t >= self._interval and self.n != self._printed_n))
        if due:
            self._line(now)
        return True

    def _line(self, now=None):
        self.fp.write(self.__str__() + "\n")
        self.fp.flush()
        self._last_line_t = self._time() if now is None else now
        self._last_mark, self._printed_n = self._mark(), self.n

    def close(self):
        if not self.disable and self._printed_n != self.n:
            self._line()  # the end, unless the last line already showed it
        self.leave = False  # the lines stay; nothing to end with a newline
        super().close()


def is_terminal(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):  # no isatty, or a closed stream
        return False


def pbar(iterable=None, *, file=None, interval: float = PLAIN_INTERVAL, **kwargs):
    """A progress bar over `iterable` (or one to `update` by hand): tqdm's on a terminal or in a
    notebook, `PlainProgress` lines anywhere else. The keywords are tqdm's (`total`, `desc`,
    `unit`, `disable`, `initial` ...); `file` defaults to stderr."""
    file = sys.stderr if file is None else file
    if _notebook_tqdm is not _std_tqdm:  # in a notebook tqdm.auto draws a widget: no stream to flood
        return _auto_tqdm(iterable, file=file, **kwargs)
    if is_terminal(file):
        return _std_tqdm(iterable, file=file, **kwargs)
    return PlainProgress(iterable, file=file, interval=interval, **kwargs)


__all__ = ["pbar", "PlainProgress", "is_terminal", "PLAIN_INTERVAL"]
