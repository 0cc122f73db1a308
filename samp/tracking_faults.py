"""What a tracking store that fails does to a run: it never fails the run (docs/runs.md, "When the tracker
fails"; docs/integrity.md).

Every call into the MLflow store goes through `call`. A store that says it is busy (a local sqlite store
locked by another process: MLflow itself waits 20 s for the lock on each call) is tried again, `ATTEMPTS`
times in all, `PAUSE_S` apart; after that, or at once for any other store error (a corrupt or unreadable
`mlflow.db`, a server that refuses), `call` raises `TrackerDown` with one line naming the store, what was
being done and the store's own first line. The caller then turns tracking off for the rest of its run and
says so in one line (`warn`); the run folder keeps everything the tracker would have had.
MLflow's own traceback of a database error (logged at ERROR by `mlflow.store.db.utils`) is held back
during the call: the one line says it.
"""

from __future__ import annotations

import logging
import sys
import time
from contextlib import contextmanager

__all__ = ["ATTEMPTS", "PAUSE_S", "TrackerDown", "call", "warn"]

ATTEMPTS = 2  # calls of a busy store, each of which MLflow lets wait 20 s for a sqlite lock
PAUSE_S = 1.0
_STORE_LOGGER = "mlflow.store.db.utils"  # logs the full traceback of each database error it re-raises


class TrackerDown(RuntimeError):
    """The tracking store could not be written; the message is one line."""


def _errors() -> tuple[type[BaseException], ...]:
    """What a store raises: MLflow's own exception (which wraps SQLAlchemy's for a local store), SQLAlchemy's
    and sqlite3's (from opening or migrating a store), and OSError (an artifact folder that cannot be written)."""
    import sqlite3

    errors: list[type[BaseException]] = [sqlite3.Error, OSError]
    try:
        from mlflow.exceptions import MlflowException

        errors.append(MlflowException)
    except ImportError:  # tracking needs mlflow; without it there is nothing of it to catch
        pass
    try:
        import sqlalchemy.exc

        errors.append(sqlalchemy.exc.SQLAlchemyError)
    except ImportError:
        pass
    return tuple(errors)


def _busy(err: BaseException) -> bool:
    text = str(err).lower()
    return "locked" in text or "busy" in text or getattr(err, "error_code", None) == "TEMPORARILY_UNAVAILABLE"


def _first_line(err: BaseException) -> str:
    lines = str(err).strip().splitlines()
    return (lines[0] if lines else type(err).__name__).rstrip(".")


@contextmanager
def _quiet_store():
    log = logging.getLogger(_STORE_LOGGER)
    before = log.disabled
    log.disabled = True
    try:
        yield
    finally:
        log.disabled = before


def call(what: str, uri: str, fn, *args, attempts: int | None = None, **kwargs):
    """`fn(*args, **kwargs)`, a call into the store `uri` doing `what` ("logging metrics"), tried again while
    the store is busy (`attempts`, default `ATTEMPTS`); TrackerDown, one line, when it fails."""
    errors = _errors()
    attempts = ATTEMPTS if attempts is None else attempts
    with _quiet_store():
        for attempt in range(1, attempts + 1):
            try:
                return fn(*args, **kwargs)
            except errors as err:
                if attempt < attempts and _busy(err):
                    time.sleep(PAUSE_S)
                    continue
                tried = f" ({attempt} tries)" if attempt > 1 else ""
                raise TrackerDown(f"the MLflow store {uri} failed while {what}{tried}: {_first_line(err)}") from None
    raise AssertionError("unreachable")  # the loop returns or raises


def warn(err: TrackerDown, folder=None) -> None:
    """The one line that says tracking is off for the rest of the run, and where the run is kept."""
    kept = f"; {folder} keeps everything the tracker would have had" if folder is not None else ""
    print(f"warning: {err}; tracking is off for the rest of this run{kept}", file=sys.stderr, flush=True)
