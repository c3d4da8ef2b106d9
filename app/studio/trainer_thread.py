"""TrainerThread: runs a ``Trainer`` in a background thread and publishes what the GUI draws.

The GUI never blocks training and never touches the trainer: it calls the thread's action
methods (``pause``, ``single_step``, ``request_save``, ``start_stage2``, ``set_stage2_settings``,
``set_view``), which only write a small lock-protected ``Controls`` record, and it reads
``status()`` (a ``TrainerStatus`` the thread publishes after each step), ``history()`` and the
latest snapshot. Everything that changes the trainer happens on the trainer thread between
steps: Stage II settings, the switch to the Stage II plan, and ``call_between_steps`` functions
(e.g. a frozen copy of the avatar for an export).

Edits (docs/editing.md): the thread owns one ``EditSession`` (``edit_session``: made with the
thread, it loads ``RUN/edits`` and autosaves there; its plan follows the switch to Stage II). The GUI
changes only the session's selection; ``edit(fn)`` runs ``fn(session)`` (apply, undo, redo) between
steps and publishes the live snapshot again, and ``guidance_steps(n)`` runs n Stage II guidance
steps; both answer through a Future."""

from __future__ import annotations

import dataclasses
import queue
import threading
import time
import traceback
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import NamedTuple

SPACES = ("observation", "canonical")


@dataclass
class Controls:
    """What the GUI asks of the trainer thread (written by the action methods, under the lock)."""

    paused: bool = False
    single_step: bool = False  # one step while paused (cleared by the trainer)
    space: str = "observation"
    frame_index: int = 0
    save: bool = False  # save a checkpoint now (cleared by the trainer)
    start_stage2: bool = False  # switch to the Stage II plan (cleared by the trainer)
    stage2: dict = field(default_factory=dict)  # Stage2Config fields the GUI sets (replaced, never mutated)
    stage2_version: int = 0  # bumped with each change of ``stage2``
    novel: str = ""  # "" (the video's poses) or a novel pose sequence shown instead (walk, arms_up)
    novel_index: int = 0  # frame of the novel sequence
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False, compare=False)

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


@dataclass(frozen=True)
class TrainerStatus:
    """The trainer as the panels see it, published by the trainer thread (read-only)."""

    stage: int = 1
    step: int = 0
    stage_step: int = 0
    planned_steps: int = 0
    planned_minutes: float | None = None
    elapsed: float = 0.0
    done: bool = False
    num_gaussians: int = 0
    has_run_folder: bool = False
    metrics: dict = field(default_factory=dict)  # latest numbers (loss, seen/unseen PSNR, λ_SDS, ...)
    stage2: dict | None = None  # the running Stage II plan's settings
    unseen_views: int = 0
    candidate_views: int = 0
    # the thread's own state
    paused: bool = False
    its: float = 0.0  # steps per second (smoothed)
    error: str | None = None  # the traceback when the loop died
    stage2_message: str | None = None  # why Stage II did not start / a setting was refused
    last_saved: str | None = None


class HistoryRow(NamedTuple):
    elapsed: float
    step: int
    loss: float
    seen_psnr: float
    unseen_psnr: float
    stage: int = 1
    val_psnr: float = float("nan")  # held-out frames of the video (or the training-view fit)


class TrainerThread:
    """Background training loop for one ``Trainer``. ``run_folder``: where Stage II is recorded
    when it starts (``RunFolder.start_stage2``); the caller holds its lock."""

    def __init__(self, trainer, controls: Controls | None = None, *, run_folder=None, publish_every: int = 5,
                 log_every: int = 25, idle_sleep: float = 0.02, novel_frames: int = 30) -> None:
        self.trainer = trainer
        self.run_folder = run_folder
        self.controls = controls or Controls()
        self.publish_every = max(1, int(publish_every))
        self.log_every = max(1, int(log_every))
        self.idle_sleep = idle_sleep
        self._history: list[HistoryRow] = self._logged_history(trainer)
        self._hist_lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.published: tuple | None = None  # (view key, step) of the last snapshot published
        self.error: str | None = None  # traceback text if the loop died
        self.last_saved: str | None = None
        self.its = 0.0  # steps per second (smoothed)
        self.stage2_message: str | None = None  # why Stage II did not start / a setting was refused
        self._stage2_applied = self.controls.get().stage2_version
        self._calls: queue.SimpleQueue = queue.SimpleQueue()
        self.novel_frames = novel_frames  # length of the novel pose sequences shown in the live view
        self._novel_cache: dict[str, list] = {}
        self._sequences: dict[str, list] = {}  # added pose sequences (motion files), by name
        self._sequences_lock = threading.Lock()
        self._status = self._make_status()
        n = len(trainer.scene.frames)
        self.controls.update(frame_index=min(max(0, self.controls.get().frame_index), n - 1))
        self.edit_session = None  # reconstruct.edits.session.EditSession (None: edit_error says why)
        self.edit_error: str | None = None
        self._make_edit_session()

    # ----- edits ----------------------------------------------------------------------------
    def _make_edit_session(self) -> None:
        """The session over the trainer's avatar (before the loop starts: no step runs meanwhile).
        It loads the run folder's edits (the avatar holds them already when the run was resumed)."""
        from reconstruct.appearance.wrap_fill import grazing_rule_for
        from reconstruct.edits.session import EditSession

        t = self.trainer
        try:
            self.edit_session = EditSession(t.state, run_dir=t.run_dir, plan=t.plan if t.stage >= 2 else None,
                                            grazing_rule=grazing_rule_for(t.config))
        except (ValueError, OSError) as exc:  # a malformed edits file: editing is off, training goes on
            self.edit_error = f"editing is off: {exc}"

    def _follow_stage(self) -> None:
        """The edit session's plan is the running Stage II plan (None in Stage I)."""
        t, session = self.trainer, self.edit_session
        if session is not None:
            plan = t.plan if t.stage >= 2 else None
            if session.plan is not plan:
                session.plan = plan

    def edit(self, fn) -> Future:
        """Run ``fn(edit_session)`` between two steps (apply / undo / redo: the session saves
        ``RUN/edits``), then publish the live snapshot again so the next frame shows the edit. The
        Future holds ``fn``'s result or its exception."""
        def call(trainer):
            if self.edit_session is None:
                raise RuntimeError(self.edit_error or "no edit session")
            self._follow_stage()
            out = fn(self.edit_session)
            self._publish(self.controls.get())
            self._status = self._make_status()
            return out
        return self.call_between_steps(call)

    def guidance_steps(self, n: int) -> Future:
        """``n`` Stage II guidance steps (the plan's canonical / observation steps, mixed by its
        canonical ratio; they train the unseen and redone regions towards the prior) between two
        steps, then a new snapshot. The Future holds the number of steps taken."""
        n = int(n)

        def call(trainer):
            plan = trainer.plan
            if trainer.stage < 2:
                raise ValueError("guidance steps need Stage II: start it first")
            if getattr(plan, "sds_note", None):
                raise ValueError(f"no guidance steps: {plan.sds_note}")
            s2 = plan.settings
            spaces = [k for k, on in (("canonical", s2.canonical_sds), ("observation", s2.observation_sds)) if on]
            if not spaces:
                raise ValueError("guidance steps are off in both spaces (Stage II settings)")

            def guidance_kind(rng):
                if len(spaces) == 1:
                    return spaces[0]
                return "canonical" if rng.random() < s2.canonical_ratio else "observation"

            plan.next_kind = guidance_kind  # this instance only, for these steps
            try:
                for _ in range(max(0, n)):
                    out = trainer.step()
                    if trainer.step_count % self.log_every == 0:
                        trainer.log_step(out)
                    self._record()
            finally:
                del plan.next_kind
            self._publish(self.controls.get())
            self._status = self._make_status()
            return n
        return self.call_between_steps(call)

    # ----- actions (any thread) ---------------------------------------------------------------
    def pause(self, paused: bool = True) -> None:
        self.controls.update(paused=paused)

    def single_step(self) -> None:
        self.controls.update(single_step=True)

    def request_save(self) -> None:
        self.controls.update(save=True)

    def start_stage2(self) -> None:
        self.controls.update(start_stage2=True)

    def set_stage2_settings(self, settings: dict) -> None:
        """Stage II settings (Stage2Config fields): used when Stage II starts, applied to the
        running plan between steps after that."""
        v = self.controls.get().stage2_version + 1
        self.controls.update(stage2=dict(settings), stage2_version=v)

    def set_view(self, **kw) -> None:
        """What the live snapshot shows: ``space``, ``frame_index``, ``novel`` (a pose sequence's
        name: a built-in novel sequence or one added with ``add_pose_sequence``; "" for the video's
        poses), ``novel_index``."""
        self.controls.update(**kw)

    def add_pose_sequence(self, key: str, poses) -> None:
        """Make ``poses`` (``BodyPose``s of the avatar's body in the scene's world, e.g. a motion
        file retargeted by ``reconstruct.motion``) a pose sequence the live view can show as
        ``set_view(novel=key, novel_index=i)``. A built-in name cannot be replaced."""
        from reconstruct.body.novel_poses import NOVEL_POSES

        poses = list(poses)
        if not key or key in NOVEL_POSES:
            raise ValueError(f"pose sequence name {key!r}: empty or a built-in sequence's")
        if not poses:
            raise ValueError(f"pose sequence {key!r}: no poses")
        with self._sequences_lock:
            self._sequences[key] = poses

    def remove_pose_sequence(self, key: str) -> None:
        """Forget a sequence added with ``add_pose_sequence`` (the view falls back to the video's poses)."""
        with self._sequences_lock:
            self._sequences.pop(key, None)

    def sequence_length(self, key: str) -> int:
        """Frames of the pose sequence ``key`` (0 when there is none by that name)."""
        from reconstruct.body.novel_poses import NOVEL_POSES

        with self._sequences_lock:
            if key in self._sequences:
                return len(self._sequences[key])
        return self.novel_frames if key in NOVEL_POSES else 0

    # ----- what the GUI reads ---------------------------------------------------------------
    def status(self) -> TrainerStatus:
        """The latest published status (the trainer thread makes a new one after each step)."""
        return self._status

    def latest_snapshot(self):
        return self.trainer.snapshots.latest()

    def history(self) -> list[HistoryRow]:
        with self._hist_lock:
            return list(self._history)

    @property
    def history_len(self) -> int:
        return len(self._history)

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    # ----- lifetime -------------------------------------------------------------------------
    def start(self) -> TrainerThread:
        if self._thread is not None:
            raise RuntimeError("TrainerThread already started")
        self._thread = threading.Thread(target=self._run, name="trainer", daemon=True)
        self._thread.start()
        return self

    def call_between_steps(self, fn) -> Future:
        """Run ``fn(trainer)`` on the trainer thread between two steps (right away, on the calling
        thread, when the loop is not running). The result comes back through the Future."""
        fut: Future = Future()
        if not self.running:
            self._call(fn, fut, self.trainer)
        else:
            self._calls.put((fn, fut))
            if not self.running:  # the loop ended meanwhile: nobody will take it
                self._drain_calls()
        return fut

    def stop(self, save: bool = True, timeout: float = 60.0) -> None:
        """Stop the loop (after the current step) and save a checkpoint when the trainer has a run folder."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
        self._drain_calls()
        if save and self.trainer.run_dir is not None and self.trainer.step_count > 0:
            self.last_saved = str(self.trainer.save())
        self._status = self._make_status()

    # ----- trainer side -----------------------------------------------------------------------
    @staticmethod
    def _call(fn, fut: Future, trainer=None) -> None:
        if not fut.set_running_or_notify_cancel():
            return
        try:
            fut.set_result(fn(trainer))
        except BaseException as exc:  # noqa: BLE001 -- handed to the caller
            fut.set_exception(exc)

    def _drain_calls(self) -> None:
        while True:
            try:
                fn, fut = self._calls.get_nowait()
            except queue.Empty:
                return
            self._call(fn, fut, self.trainer)

    def _make_status(self) -> TrainerStatus:
        t = self.trainer
        plan = t.plan
        s = plan.settings
        stage2 = s.to_dict() if t.stage == 2 else None
        views = getattr(plan, "selected_views", [])
        return TrainerStatus(
            stage=t.stage, step=t.step_count, stage_step=t.stage_step, planned_steps=s.iters,
            planned_minutes=s.minutes, elapsed=t.elapsed, done=t.done, num_gaussians=t.state.num_gaussians,
            has_run_folder=t.run_dir is not None,
            metrics={k: v for k, v in t.latest.items() if isinstance(v, (int, float))},
            stage2=stage2, unseen_views=sum(v.unseen for v in views), candidate_views=len(views),
            paused=self.controls.get().paused, its=self.its, error=self.error, stage2_message=self.stage2_message,
            last_saved=self.last_saved)

    @staticmethod
    def _logged_history(trainer) -> list[HistoryRow]:
        """A reopened run's curves so far, from its metrics log (training losses and evaluations)."""
        if trainer.log is None:
            return []
        rows, seen, unseen, val, nan = [], float("nan"), float("nan"), float("nan"), float("nan")
        try:
            records = trainer.log.read()
        except (OSError, ValueError):
            return []
        for r in records:
            if r.get("kind") == "eval":
                seen = float(r.get("seen_psnr") or nan)
                unseen = float(r.get("unseen_psnr") or nan)
                val = float(r.get("val_psnr") or nan)
            elif "loss" not in r:
                continue
            rows.append(HistoryRow(float(r.get("elapsed", 0.0)), int(r.get("step", 0)), float(r.get("loss", nan)),
                                   seen, unseen, int(r.get("stage", 1)), val))
        return rows

    def _record(self) -> None:
        t = self.trainer
        lat = t.latest
        nan = float("nan")
        row = HistoryRow(float(t.elapsed), int(t.step_count), float(lat.get("loss", nan)),
                         float(lat.get("seen_psnr", nan)), float(lat.get("unseen_psnr", nan)), t.stage,
                         float(lat.get("val_psnr", nan)))
        with self._hist_lock:
            self._history.append(row)

    @property
    def novel_length(self) -> int:
        return self.novel_frames

    def _novel_poses(self, name: str) -> list | None:
        """The poses of the sequence ``name``: an added one, or a built-in novel sequence (made once);
        None when there is no sequence by that name (e.g. just removed)."""
        with self._sequences_lock:
            if name in self._sequences:
                return self._sequences[name]
        if name not in self._novel_cache:
            from reconstruct.body.novel_poses import NOVEL_POSES, novel_pose_sequence

            if name not in NOVEL_POSES:
                return None
            t = self.trainer
            self._novel_cache[name] = novel_pose_sequence(t.state.body, name, self.novel_frames,
                                                          base=t.scene.frames[0].pose)
        return self._novel_cache[name]

    def _view_key(self, c: Controls) -> tuple:
        frame = min(max(0, int(c.frame_index)), len(self.trainer.scene.frames) - 1)
        n = self.sequence_length(c.novel) if c.novel else 0
        if n:
            return ("observation", frame, c.novel, int(c.novel_index) % n)
        return (c.space, frame, "", 0)

    def _publish(self, c: Controls) -> None:
        key = self._view_key(c)
        space, frame, novel, k = key
        t = self.trainer
        poses = self._novel_poses(novel) if novel else None
        if poses:
            t.snapshots.publish(t.avatar().snapshot_at_pose(poses[k % len(poses)], frame))
        else:
            t.publish(space, frame)
        self.published = (key, t.step_count)

    def _stage2_config(self, settings: dict):
        from reconstruct import config as config_layer
        from reconstruct.stage2.config import Stage2Config

        return config_layer.from_dict(Stage2Config, settings, "Stage II")

    def _start_stage2(self, c: Controls) -> None:
        t = self.trainer
        if t.stage >= 2:
            self.stage2_message = "Stage II is already running"
            return
        try:
            config = self._stage2_config(c.stage2)
        except (TypeError, ValueError) as exc:
            self.stage2_message = f"Stage II settings refused: {exc}"
            return
        try:
            if self.run_folder is not None:
                self.run_folder.start_stage2(t, config, allow_incomplete=True)
            else:
                from reconstruct.stage2.plan import start_stage2

                start_stage2(t, config, allow_incomplete=True)
        except Exception as exc:  # noqa: BLE001 -- shown in the panel; Stage I goes on
            self.stage2_message = f"Stage II could not start: {type(exc).__name__}: {exc}"
            return
        self._stage2_applied = c.stage2_version  # the settings went into the new plan
        self.stage2_message = None
        self.published = None
        self._follow_stage()  # edits made from now on follow the Stage II plan (views, pseudo-colours)

    def _apply_stage2_settings(self, c: Controls) -> None:
        """The GUI's Stage II settings for the running plan, validated as a whole first; view
        selection is redone when the visibility threshold changed."""
        self._stage2_applied = c.stage2_version
        t = self.trainer
        try:
            config = self._stage2_config({**t.plan.settings.to_dict(), **c.stage2})
        except (TypeError, ValueError) as exc:
            self.stage2_message = f"Stage II settings refused: {exc}"
            return
        t.plan.update_settings(config, t.state)
        self.stage2_message = None

    def _between_steps(self, c: Controls) -> Controls:
        self._drain_calls()
        if self.controls.take("start_stage2"):
            self._start_stage2(c)
        if self.trainer.stage >= 2 and c.stage2_version != self._stage2_applied:
            self._apply_stage2_settings(c)
        return c

    def _run(self) -> None:
        t = self.trainer
        try:
            t.maybe_evaluate(force=t.stage_step == 0)
            self._record()
            self._publish(self.controls.get())
            stage = t.stage
            t_last = time.perf_counter()
            while not self._stop.is_set():
                c = self._between_steps(self.controls.get())
                if t.stage != stage:  # Stage I -> Stage II
                    stage = t.stage
                    self._record()
                    self._publish(c)
                if self.controls.take("save") and t.run_dir is not None:
                    self.last_saved = str(t.save())
                want_step = (not c.paused and not t.done) or self.controls.take("single_step")
                if not want_step:
                    if (self._view_key(c), t.step_count) != self.published:
                        self._publish(c)
                    self.its = 0.0
                    self._status = self._make_status()
                    time.sleep(self.idle_sleep)
                    t_last = time.perf_counter()
                    continue
                _, evaluated = t.advance(self.log_every)
                now = time.perf_counter()
                if evaluated is None:  # steps per second of training, evaluations left out
                    dt = max(now - t_last, 1e-6)
                    self.its = 1.0 / dt if self.its == 0 else 0.9 * self.its + 0.1 / dt
                t_last = now
                self._record()
                c = self.controls.get()
                changed = self.published is None or self.published[0] != self._view_key(c)
                if changed or t.step_count % self.publish_every == 0 or c.paused or t.done:
                    self._publish(c)
                self._status = self._make_status()
        except Exception:  # noqa: BLE001 -- shown in the GUI, training stops
            self.error = traceback.format_exc()
        finally:
            self._status = self._make_status()
            self._drain_calls()
