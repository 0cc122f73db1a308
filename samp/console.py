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
import re
import sys
import time
from pathlib import Path

__all__ = ["Progress", "as_installed", "import_pybullet", "is_terminal", "plural"]


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


def plural(n: int, word: str, many: str | None = None) -> str:
    """`n` and `word` agreeing in number: "1 problem", "3 problems", `plural(2, "entry", "entries")`."""
    return f"{n} {word if n == 1 else (many or word + 's')}"


def _console_scripts() -> dict[str, str]:
    """{"samp.train": "samp-train", ...}: the modules `python -m` runs, by the command installed for each
    (pyproject.toml's [project.scripts], read back from the installed package)."""
    from importlib import metadata

    try:
        scripts = metadata.entry_points(group="console_scripts")
    except Exception:  # broken metadata of some other package: no names to offer, the text stays as written
        return {}
    return {ep.name.replace("-", "."): ep.name for ep in scripts if ep.value.startswith("samp.")}


_PYTHON_M = re.compile(r"python -m (samp\.\w+)(?![\w.])")  # not `samp.data.shards`, which has no command
_CONF = re.compile(r"(?<![\w./-])conf/([\w./*<>{}-]*[\w/*>}])?")


def as_installed(text: str) -> str:
    """Help text in the terms of the command being run. Started through a console command (`samp-data`),
    `python -m samp.X` is named by its command: the interpreter on PATH need not be the one samp is
    installed in (pipx, a venv not activated). Running from configs other than a clone's `conf/` (an
    installed wheel, `SAMP_CONF_DIR`), `conf/X` is "X in the shipped configs", and their folder is named."""
    from samp.paths import REPO_ROOT, packaged_conf_dir

    scripts = _console_scripts()
    if Path(sys.argv[0]).stem in scripts.values():
        text = _PYTHON_M.sub(lambda m: scripts.get(m.group(1), m.group(0)), text)
    try:
        own = packaged_conf_dir()
    except FileNotFoundError:  # said by the command itself when it reads a config
        return text
    if own.resolve() != (REPO_ROOT / "conf").resolve() and _CONF.search(text):
        text = _CONF.sub(lambda m: f"{m.group(1) or ''} in the shipped configs".lstrip(), text)
        text += f"\n\nthe shipped configs: {own}"
    return text
