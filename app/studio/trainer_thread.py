"""TrainerThread: runs ``TrainingSession.step()`` in a background thread and publishes snapshots.

The GUI never blocks training: it only writes a small lock-protected ``Controls`` record and reads
``session.snapshots.latest()`` and copies of the history. Everything that changes the session
happens on the trainer thread between steps: Stage II settings from ``Controls.stage2`` are copied
into ``session.stage2``, "Start Stage II" swaps ``self.session`` for a ``Stage2Session`` taking over
the Stage I one, and ``call_between_steps`` runs a function on the session (e.g. a frozen copy of
the avatar for an export). The GUI must read the session through ``trainer.session``."""

from __future__ import annotations

import dataclasses
import importlib
import queue
import threading
import time
import traceback
from concurrent.futures import Future
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
    start_stage2: bool = False  # take the Stage I session over into Stage II (cleared by the trainer)
    stage2: dict = dataclasses.field(default_factory=dict)  # Stage2Config fields the GUI sets (replace, never mutate)
    stage2_version: int = 0  # bumped with each change of ``stage2``
    novel: str = ""  # "" (the video's poses) or a novel pose sequence shown instead (walk, arms_up)
    novel_index: int = 0  # frame of the novel sequence
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
    stage: int = 1


STAGE2_MODULE = "reconstruct.stage2.session"
STAGE2_SETTINGS = ("given_view_ratio", "canonical_ratio", "lambda_sds", "sds_t0", "sds_k", "progressive",
                   "visibility_threshold", "prior", "prior_path")


class TrainerThread:
    """Background training loop for one ``TrainingSession``."""

    def __init__(self, session, controls: Controls | None = None, *, publish_every: int = 5,
                 log_every: int = 25, idle_sleep: float = 0.02) -> None:
        self.session = session
        self.controls = controls or Controls()
        self.publish_every = max(1, int(publish_every))
        self.log_every = max(1, int(log_every))
        self.idle_sleep = idle_sleep
        self._history: list[HistoryRow] = self._logged_history(session)
        self._hist_lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._published: tuple | None = None  # (space, frame, step) of the last snapshot
        self.error: str | None = None  # traceback text if the loop died
        self.last_saved: str | None = None
        self.its = 0.0  # steps per second (smoothed)
        self.stage2_message: str | None = None  # why Stage II did not start / a setting was refused
        self._stage2_applied = self.controls.get().stage2_version
        self._calls: queue.SimpleQueue = queue.SimpleQueue()
        self.novel_frames = 30  # length of the novel pose sequences shown in the live view
        self._novel_cache: dict[str, list] = {}
        n = len(session.scene.frames)
        self.controls.update(frame_index=min(max(0, self.controls.get().frame_index), n - 1))

    # ----- GUI side ---------------------------------------------------------------------------
    def history(self) -> list[HistoryRow]:
        with self._hist_lock:
            return list(self._history)

    @property
    def history_len(self) -> int:
        return len(self._history)

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def start(self) -> TrainerThread:
        if self._thread is not None:
            raise RuntimeError("TrainerThread already started")
        self._thread = threading.Thread(target=self._run, name="trainer", daemon=True)
        self._thread.start()
        return self

    def call_between_steps(self, fn) -> Future:
        """Run ``fn(session)`` on the trainer thread between two steps (right away, on the calling
        thread, when the loop is not running). The result comes back through the Future."""
        fut: Future = Future()
        if not self.running:
            self._call(fn, fut, self.session)
        else:
            self._calls.put((fn, fut))
            if not self.running:  # the loop ended meanwhile: nobody will take it
                self._drain_calls()
        return fut

    def stop(self, save: bool = True, timeout: float = 60.0) -> None:
        """Stop the loop (after the current step) and save a checkpoint when the session has a run folder."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
        self._drain_calls()
        if save and self.session.run_dir is not None and self.session.step_count > 0:
            self.last_saved = str(self.session.save())

    # ----- trainer side -----------------------------------------------------------------------
    @staticmethod
    def _call(fn, fut: Future, session=None) -> None:
        if not fut.set_running_or_notify_cancel():
            return
        try:
            fut.set_result(fn(session))
        except BaseException as exc:  # noqa: BLE001 -- handed to the caller
            fut.set_exception(exc)

    def _drain_calls(self) -> None:
        while True:
            try:
                fn, fut = self._calls.get_nowait()
            except queue.Empty:
                return
            self._call(fn, fut, self.session)

    @staticmethod
    def _logged_history(session) -> list[HistoryRow]:
        """A reopened run's curves so far, from its metrics log (training losses and evaluations)."""
        log = getattr(session, "log", None)
        if log is None:
            return []
        rows, seen, unseen, nan = [], float("nan"), float("nan"), float("nan")
        try:
            records = log.read()
        except (OSError, ValueError):
            return []
        for r in records:
            if r.get("kind") == "eval":
                seen = float(r.get("seen_psnr") or nan)
                unseen = float(r.get("unseen_psnr") or nan)
            elif "loss" not in r:
                continue
            rows.append(HistoryRow(float(r.get("elapsed", 0.0)), int(r.get("step", 0)), float(r.get("loss", nan)),
                                   seen, unseen, int(r.get("stage", 1))))
        return rows

    def _record(self) -> None:
        s = self.session
        lat = s.latest
        nan = float("nan")
        row = HistoryRow(float(s.elapsed), int(s.step_count), float(lat.get("loss", nan)),
                         float(lat.get("seen_psnr", nan)), float(lat.get("unseen_psnr", nan)), s.stage)
        with self._hist_lock:
            self._history.append(row)

    @property
    def novel_length(self) -> int:
        return self.novel_frames

    def _novel_poses(self, name: str) -> list:
        if name not in self._novel_cache:
            from reconstruct.body.novel_poses import novel_pose_sequence

            s = self.session
            self._novel_cache[name] = novel_pose_sequence(s.body, name, self.novel_frames, base=s.scene.frames[0].pose)
        return self._novel_cache[name]

    def _view_key(self, c: Controls) -> tuple:
        frame = min(max(0, int(c.frame_index)), len(self.session.scene.frames) - 1)
        if c.novel:
            return ("observation", frame, c.novel, int(c.novel_index) % self.novel_frames)
        return (c.space, frame, "", 0)

    def _publish(self, c: Controls) -> None:
        key = self._view_key(c)
        space, frame, novel, k = key
        if novel:
            from app.export import _snapshot_at_pose

            self.session.snapshots.publish(_snapshot_at_pose(self.session, self._novel_poses(novel)[k], frame))
        else:
            self.session.publish(space, frame)
        self._published = (key, self.session.step_count)

    def _start_stage2(self, c: Controls) -> None:
        s = self.session
        if s.stage >= 2:
            self.stage2_message = "Stage II is already running"
            return
        try:
            from reconstruct.stage2.config import Stage2Config

            config = Stage2Config(**{k: v for k, v in c.stage2.items() if k in STAGE2_SETTINGS})
        except (TypeError, ValueError) as exc:
            self.stage2_message = f"Stage II settings refused: {exc}"
            return
        try:
            module = importlib.import_module(STAGE2_MODULE)
            factory = module.Stage2Session.from_stage1
        except (ImportError, AttributeError) as exc:
            self.stage2_message = (f"Stage II is not available in this version ({STAGE2_MODULE}: "
                                   f"{type(exc).__name__}: {exc})")
            return
        try:
            new = factory(s, config)
        except Exception as exc:  # noqa: BLE001 -- shown in the panel; Stage I goes on
            self.stage2_message = f"Stage II could not start: {type(exc).__name__}: {exc}"
            return
        self.session = new
        self._stage2_applied = c.stage2_version  # the settings went into the new session's config
        self.stage2_message = None
        self._published = None

    def _apply_stage2_settings(self, c: Controls) -> None:
        """Copy the GUI's Stage II settings into ``session.stage2`` (validated as a whole first);
        re-run view selection when the visibility threshold changed."""
        self._stage2_applied = c.stage2_version
        s = self.session
        cfg = s.stage2
        fields = {k: v for k, v in c.stage2.items() if k in STAGE2_SETTINGS}
        try:
            dataclasses.replace(cfg, **fields)  # validates the combination
        except (TypeError, ValueError) as exc:
            self.stage2_message = f"Stage II settings refused: {exc}"
            return
        old_threshold = cfg.visibility_threshold
        for k, v in fields.items():
            setattr(cfg, k, v)
        self.stage2_message = None
        if cfg.visibility_threshold != old_threshold:
            s.reselect_views()

    def _between_steps(self, c: Controls) -> Controls:
        self._drain_calls()
        if self.controls.take("start_stage2"):
            self._start_stage2(c)
        if self.session.stage >= 2 and c.stage2_version != self._stage2_applied:
            self._apply_stage2_settings(c)
        return c

    def _run(self) -> None:
        s = self.session
        try:
            s.maybe_evaluate(force=s.step_count == 0)
            self._record()
            self._publish(self.controls.get())
            t_last = time.perf_counter()
            while not self._stop.is_set():
                c = self._between_steps(self.controls.get())
                if self.session is not s:  # Stage I -> Stage II
                    s = self.session
                    self._record()
                    self._publish(c)
                if self.controls.take("save") and s.run_dir is not None:
                    self.last_saved = str(s.save())
                want_step = (not c.paused and not s.done) or self.controls.take("single_step")
                if not want_step:
                    if (self._view_key(c), s.step_count) != self._published:
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
                changed = self._published is None or self._published[0] != self._view_key(c)
                if changed or s.step_count % self.publish_every == 0 or c.paused or s.done:
                    self._publish(c)
        except Exception:  # noqa: BLE001 -- shown in the GUI, training stops
            self.error = traceback.format_exc()
        finally:
            self._drain_calls()

