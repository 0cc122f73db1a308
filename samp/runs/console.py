"""A run's console: everything it prints kept in `<run>/train.log`, progress as plain lines when the output
is not a terminal, and Lightning's advertising left out.

`RunLog` copies what the process writes to `sys.stdout` and `sys.stderr` (and what Lightning logs through
`logging`) into the run's `train.log`, while it still reaches the console. Output from before the run folder
exists (building a missing dataset) is held in memory and written first, so the file has the whole run.
Progress bars redraw a line with carriage returns on a terminal; the file keeps only the last state of each
such line, without terminal control sequences.

`LineProgress` stands in for Lightning's progress bar when stderr is not a terminal (a cluster log, CI,
`make demo > log`): one line per epoch and, within long epochs, one every `every_s` seconds.
"""

from __future__ import annotations

import io
import logging
import re
import sys
import time
from pathlib import Path

import pytorch_lightning as pl

from samp.console import is_terminal

__all__ = ["LineProgress", "RunLog", "quiet_lightning", "trainer_console"]

LIGHTNING_LOGGERS = ("pytorch_lightning", "lightning_fabric", "lightning.pytorch", "lightning.fabric")
_ANSI = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]")  # cursor moves and colours


class _DropTips(logging.Filter):
    """Lightning's "💡 Tip: ... litlogger" advert (logged at info level at every Trainer start)."""

    def filter(self, record: logging.LogRecord) -> bool:
        return "Tip:" not in record.getMessage()


def quiet_lightning() -> None:
    """Leave Lightning's tips out of its console and file handlers, its own internal deprecation notice
    about `LeafSpec` (raised inside Lightning, nothing a user can change), and its notice of modules in eval
    mode at the start of training: samp's systems freeze the robot SDF they query on purpose (`requires_grad_
    (False).eval()` in samp.policy.system), so the notice came with every SAMP run and meant nothing."""
    import warnings

    for name in LIGHTNING_LOGGERS:
        for handler in logging.getLogger(name).handlers:
            if not any(isinstance(f, _DropTips) for f in handler.filters):
                handler.addFilter(_DropTips())
    warnings.filterwarnings("ignore", message=r".*isinstance\(treespec, LeafSpec\)")
    warnings.filterwarnings("ignore", message=r"Found \d+ module\(s\) in eval mode at the start of training")


class _LogSink:
    """Text written to the console, as a log file should hold it: carriage-return redraws collapsed to the
    line's last state, terminal control sequences removed. Buffered in memory until `open(path)`; after
    `close()` it takes nothing more (see `write`)."""

    def __init__(self):
        self._file: io.TextIOBase = io.StringIO()
        self._line = ""  # the current line, not yet ended by "\n"
        self.closed = False

    def write(self, text: str) -> None:
        # A stream handed out during the run can outlive it: a logging handler or an atexit hook of another
        # package that kept `sys.stderr` writes through the tee at interpreter exit, after train.log is closed.
        # Such text still reaches the console (`_Tee`); the log file, finished, takes no more of it.
        if self.closed:
            return
        for piece in re.split(r"(\n)", _ANSI.sub("", text)):
            if piece == "\n":
                self._file.write(self._line + "\n")
                self._line = ""
            elif piece:
                self._line = (self._line + piece).rpartition("\r")[2] if "\r" in piece else self._line + piece
        self._file.flush()

    def open(self, path: Path) -> None:
        held = self._file.getvalue() if isinstance(self._file, io.StringIO) else ""
        self._file = open(path, "a", encoding="utf-8")
        self._file.write(held)
        self._file.flush()

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        if self._line:
            self._file.write(self._line + "\n")
            self._line = ""
        self._file.close()


class _Tee:
    """A text stream that writes to the console stream it replaces and to a `_LogSink`."""

    def __init__(self, stream, sink: _LogSink):
        self._stream, self._sink = stream, sink

    def write(self, text: str) -> int:
        self._sink.write(text)
        return self._stream.write(text)

    def flush(self) -> None:
        self._stream.flush()

    def isatty(self) -> bool:  # progress bars decide by the real console
        return is_terminal(self._stream)

    def __getattr__(self, name):
        return getattr(self._stream, name)


class RunLog:
    """`with RunLog() as log: ...; log.attach(run_folder)`: tee stdout, stderr and Lightning's log records
    into `<run_folder>/train.log` (appended to, so a resumed run continues its file)."""

    def __init__(self, name: str = "train.log"):
        self.name, self.path = name, None
        self._sink = _LogSink()
        self._handler: logging.Handler | None = None

    def __enter__(self) -> "RunLog":
        self._saved = sys.stdout, sys.stderr
        sys.stdout, sys.stderr = _Tee(sys.stdout, self._sink), _Tee(sys.stderr, self._sink)
        return self

    def attach(self, folder: Path) -> Path:
        """Start writing `folder/train.log` (with what was printed before this call)."""
        self.path = Path(folder) / self.name
        self._sink.open(self.path)
        self._handler = logging.StreamHandler(_SinkStream(self._sink))
        self._handler.setFormatter(logging.Formatter("%(message)s"))
        self._handler.addFilter(_DropTips())
        for name in LIGHTNING_LOGGERS:  # they do not propagate to the root: hand them the file themselves
            logging.getLogger(name).addHandler(self._handler)
        logging.getLogger("samp").addHandler(self._handler)
        return self.path

    def discard(self) -> None:
        """Keep no log (a DDP rank other than 0, whose run folder is rank 0's): stop holding output in memory."""
        import os

        self._sink._file = open(os.devnull, "w", encoding="utf-8")
        self.path = Path(os.devnull)

    def __exit__(self, *exc) -> None:
        try:
            sys.stdout.flush()
            sys.stderr.flush()
        finally:  # the console streams come back whatever happened, before the file is closed
            sys.stdout, sys.stderr = self._saved
            if self._handler is not None:
                for name in (*LIGHTNING_LOGGERS, "samp"):
                    logging.getLogger(name).removeHandler(self._handler)
            self._sink.close()  # unattached: the text held in memory is let go


class _SinkStream:
    def __init__(self, sink: _LogSink):
        self._sink = sink

    def write(self, text: str) -> None:
        self._sink.write(text)

    def flush(self) -> None:
        pass


class LineProgress(pl.Callback):
    """Training progress as plain lines: one at the end of each epoch (with the validation loss when there
    is one) and one every `every_s` seconds within an epoch. For logs that are not a terminal."""

    def __init__(self, every_s: float = 60.0, stream=None):
        self.every_s, self.stream = float(every_s), stream

    def _print(self, text: str) -> None:
        stream = self.stream or sys.stderr
        stream.write(text + "\n")
        stream.flush()

    @staticmethod
    def _metrics(trainer, prefix: str) -> str:
        items = [(k, v) for k, v in trainer.callback_metrics.items() if k.startswith(prefix) and v.numel() == 1]
        return " ".join(f"{k}={float(v):.4g}" for k, v in sorted(items))

    def on_train_start(self, trainer, pl_module) -> None:
        self._start = self._last = time.perf_counter()

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        now = time.perf_counter()
        if now - self._last >= self.every_s:
            self._last = now
            total = trainer.num_training_batches
            self._print(f"epoch {trainer.current_epoch} batch {batch_idx + 1}/{total} step {trainer.global_step} "
                        f"({now - self._start:.0f} s) {self._metrics(trainer, 'train/')}".rstrip())

    def on_train_epoch_end(self, trainer, pl_module) -> None:
        if trainer.sanity_checking:
            return
        self._last = now = time.perf_counter()
        lr = ""
        if trainer.optimizers:
            lr = f" lr={trainer.optimizers[0].param_groups[0]['lr']:.3g}"
        self._print(f"epoch {trainer.current_epoch} done: step {trainer.global_step} ({now - self._start:.0f} s)"
                    f"{lr} {self._metrics(trainer, 'train/')} {self._metrics(trainer, 'val/')}".rstrip())


def trainer_console(trainer_cfg, stream=None) -> tuple[dict, list]:
    """(trainer keyword overrides, extra callbacks): Lightning's bar on a terminal, else `LineProgress`."""
    if not trainer_cfg.get("enable_progress_bar", True) or is_terminal(stream):
        return {}, []
    return {"enable_progress_bar": False}, [LineProgress(stream=stream)]
