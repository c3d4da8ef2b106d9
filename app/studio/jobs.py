"""Work the GL thread hands off: ``BackgroundJob`` runs one function in a daemon thread (reading a
motion file and retargeting it, reading a .ply) and the GL thread polls it once per frame, never
waiting on it. Errors come back as text for the panel that asked."""

from __future__ import annotations

import threading
import time
import traceback
from collections.abc import Callable
from typing import Generic, TypeVar

T = TypeVar("T")

# errors that are the file's or the user's (shown as they are); anything else also gets its traceback on stderr
EXPECTED_ERRORS = (ValueError, OSError, KeyError)


class BackgroundJob(Generic[T]):
    """``fn()`` in a daemon thread. Any thread: ``done``, ``result`` (when it succeeded), ``error``
    (one line: the exception's type and message), ``seconds`` (how long it ran)."""

    def __init__(self, fn: Callable[[], T], name: str = "job") -> None:
        self.name = name
        self.result: T | None = None
        self.error: str | None = None
        self.seconds: float | None = None
        self._fn = fn
        self._t0 = time.perf_counter()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    @property
    def done(self) -> bool:
        return not self._thread.is_alive()

    def join(self, timeout: float | None = None) -> None:
        self._thread.join(timeout)

    def _run(self) -> None:
        try:
            self.result = self._fn()
        except Exception as exc:  # noqa: BLE001 -- shown in the panel that started the job
            self.error = f"{type(exc).__name__}: {exc}" if not isinstance(exc, EXPECTED_ERRORS) or not str(exc) \
                else str(exc)
            if not isinstance(exc, EXPECTED_ERRORS):
                traceback.print_exc()
        finally:
            self.seconds = time.perf_counter() - self._t0


def take_finished(holder, what: str) -> BackgroundJob | None:
    """``holder.job`` once it has finished (``holder.job`` is cleared), or None while it runs or
    when there is none. A job that failed leaves ``holder.message`` saying "could not open
    ``what``" (and stderr) and gives None too. For the GL thread: it never waits."""
    import sys

    job = holder.job
    if job is None or not job.done:
        return None
    holder.job = None
    if job.error is not None:
        holder.message = f"could not open {what}: {job.error}"
        print(f"wonderhuman-studio: {holder.message}", file=sys.stderr)
        return None
    return job
