"""TrainerThread: runs ``TrainingSession.step()`` in a background thread and publishes snapshots.

The GUI never blocks training: it only writes a small lock-protected ``Controls`` record and reads
``session.snapshots.latest()`` and copies of the history."""

from __future__ import annotations

import dataclasses
import threading
import time
import traceback
from dataclasses import dataclass
from typing import NamedTuple

SPACES = ("observation", "canonical")


@dataclass
class Controls:
    """What the GUI asks of the trainer. Use ``get()`` / ``update()``: both take the lock."""

    paused: bool = False
    single_step: bool = False  # one step while paused (cleared by the trainer)
    space: str = "observation"
    frame_index: int = 0
    save: bool = False  # save a checkpoint now (cleared by the trainer)
    _lock: threading.Lock = dataclasses.field(default_factory=threading.Lock, repr=False, compare=False)

    def get(self) -> Controls:
        with self._lock:
            return dataclasses.replace(self, _lock=threading.Lock())

    def update(self, **kw) -> None:
        if "space" in kw and kw["space"] not in SPACES:
            raise ValueError(f"space must be one of {SPACES}, found {kw['space']!r}")
        with self._lock:
            for k, v in kw.items():
                if k.startswith("_") or not hasattr(self, k):
                    raise AttributeError(f"Controls has no setting {k!r}")
                setattr(self, k, v)

    def take(self, name: str) -> bool:
        """Read and clear a one-shot request."""
        with self._lock:
            value = getattr(self, name)
            setattr(self, name, False)
            return bool(value)


class HistoryRow(NamedTuple):
    elapsed: float
    step: int
    loss: float
    seen_psnr: float
    unseen_psnr: float


class TrainerThread:
    """Background training loop for one ``TrainingSession``."""

    def __init__(self, session, controls: Controls | None = None, *, publish_every: int = 5,
                 log_every: int = 25, idle_sleep: float = 0.02) -> None:
        self.session = session
        self.controls = controls or Controls()
        self.publish_every = max(1, int(publish_every))
        self.log_every = max(1, int(log_every))
        self.idle_sleep = idle_sleep
        self._history: list[HistoryRow] = []
        self._hist_lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._published: tuple | None = None  # (space, frame, step) of the last snapshot
        self.error: str | None = None  # traceback text if the loop died
        self.last_saved: str | None = None
        self.its = 0.0  # steps per second (smoothed)
        n = len(session.scene.frames)
        self.controls.update(frame_index=min(max(0, self.controls.get().frame_index), n - 1))

    # ----- GUI side ---------------------------------------------------------------------------
    def history(self) -> list[HistoryRow]:
        with self._hist_lock:
            return list(self._history)

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def start(self) -> TrainerThread:
        if self._thread is not None:
            raise RuntimeError("TrainerThread already started")
        self._thread = threading.Thread(target=self._run, name="trainer", daemon=True)
        self._thread.start()
        return self

    def stop(self, save: bool = True, timeout: float = 60.0) -> None:
        """Stop the loop (after the current step) and save a checkpoint when the session has a run folder."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
        if save and self.session.run_dir is not None and self.session.step_count > 0:
            self.last_saved = str(self.session.save())

    # ----- trainer side -----------------------------------------------------------------------
    def _record(self) -> None:
        s = self.session
        lat = s.latest
        nan = float("nan")
        row = HistoryRow(float(s.elapsed), int(s.step_count), float(lat.get("loss", nan)),
                         float(lat.get("seen_psnr", nan)), float(lat.get("unseen_psnr", nan)))
        with self._hist_lock:
            self._history.append(row)

    def _publish(self, c: Controls) -> None:
        frame = min(max(0, int(c.frame_index)), len(self.session.scene.frames) - 1)
        self.session.publish(c.space, frame)
        self._published = (c.space, frame, self.session.step_count)

    def _run(self) -> None:
        s = self.session
        try:
            s.maybe_evaluate(force=s.step_count == 0)
            self._record()
            self._publish(self.controls.get())
            t_last = time.perf_counter()
            while not self._stop.is_set():
                c = self.controls.get()
                if self.controls.take("save") and s.run_dir is not None:
                    self.last_saved = str(s.save())
                want_step = (not c.paused and not s.done) or self.controls.take("single_step")
                if not want_step:
                    key = (c.space, min(max(0, c.frame_index), len(s.scene.frames) - 1), s.step_count)
                    if key != self._published:
                        self._publish(c)
                    self.its = 0.0
                    time.sleep(self.idle_sleep)
                    t_last = time.perf_counter()
                    continue
                _, evaluated = s.advance(self.log_every)
                now = time.perf_counter()
                if evaluated is None:  # steps per second of training, evaluations left out
                    dt = max(now - t_last, 1e-6)
                    self.its = 1.0 / dt if self.its == 0 else 0.9 * self.its + 0.1 / dt
                t_last = now
                self._record()
                c = self.controls.get()
                changed = self._published is None or self._published[:2] != (c.space, c.frame_index)
                if changed or s.step_count % self.publish_every == 0 or c.paused or s.done:
                    self._publish(c)
        except Exception:  # noqa: BLE001 -- shown in the GUI, training stops
            self.error = traceback.format_exc()

