"""What samp prints while it works: progress that suits where the output goes, and pybullet without its banner.

On a terminal a progress bar redraws itself in place; in a file (a cluster job's log, CI, `make demo > log`)
every redraw would stay as a line of its own, so there `Progress` writes one plain line now and then
(every `every_s` seconds, and at the end) instead.

pybullet's C extension writes "pybullet build time: ..." to stderr (file descriptor 2, below Python's
`sys.stderr`) when it is imported, once per process: each dataset worker and evaluation printed it again.
`import_pybullet` imports it with descriptor 2 pointed at /dev/null for that moment.
"""

from __future__ import annotations

import os
import sys
import time

__all__ = ["Progress", "import_pybullet", "is_terminal"]


def is_terminal(stream=None) -> bool:
    """Whether `stream` (default: stderr, where progress goes) is an interactive terminal."""
    stream = sys.stderr if stream is None else stream
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):  # closed or not a real stream
        return False


def import_pybullet():
    """`import pybullet`, without the build-time banner its C code writes to stderr on import."""
    if "pybullet" in sys.modules:
        return sys.modules["pybullet"]
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (AttributeError, ValueError, OSError):  # no descriptor 2 to guard
        import pybullet

        return pybullet
    try:
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, 2)
        os.close(null)
        import pybullet
    finally:
        os.dup2(saved, 2)
        os.close(saved)
    return pybullet


class Progress:
    """A progress counter: a tqdm bar on a terminal, else a line at most every `every_s` seconds and, when
    it printed one of those or ran for `every_s` seconds or more, a last one at the end (so short tasks stay
    silent in a log). Use as a context manager, or call `close()`.

    total: how many units make the whole task (None: unknown). `stream` defaults to stderr."""

    def __init__(self, total: int | None, desc: str, unit: str = "it", every_s: float = 30.0, stream=None,
                 enabled: bool = True):
        self.total, self.desc, self.unit, self.every_s = total, desc, unit, float(every_s)
        self.stream = sys.stderr if stream is None else stream
        self.n, self.enabled, self._closed, self._lines = 0, enabled, False, 0
        self._start = self._last = time.perf_counter()
        self._bar = None
        if enabled and is_terminal(self.stream):
            from tqdm.auto import tqdm

            self._bar = tqdm(total=total, desc=desc, unit=unit, file=self.stream, smoothing=0.05)

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def update(self, n: int = 1) -> None:
        self.n += n
        if self._bar is not None:
            self._bar.update(n)
            return
        now = time.perf_counter()
        if self.enabled and now - self._last >= self.every_s:
            self._last = now
            self._line()

    def _line(self, final: bool = False) -> None:
        self._lines += 1
        elapsed = time.perf_counter() - self._start
        of = f"/{self.total}" if self.total is not None else ""
        pct = f" ({100.0 * self.n / self.total:.0f} %)" if self.total else ""
        rate = f", {self.n / elapsed:.2f} {self.unit}/s" if elapsed > 0 and self.n else ""
        self.stream.write(f"{self.desc}: {self.n}{of} {self.unit}{pct} in {elapsed:.1f} s{rate}"
                          f"{' (done)' if final else ''}\n")
        self.stream.flush()

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        if self._bar is not None:
            self._bar.close()
        elif self.enabled and (self._lines or time.perf_counter() - self._start >= self.every_s):
            self._line(final=True)
