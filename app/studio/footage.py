"""Your own footage from the window: ``prepare`` a video, an image or a folder of images into a scene
folder in the background (its log lines, report and picture shown as they come), then train on it.

Both steps run in ``BackgroundJob`` threads and the GL thread only polls them:
* ``prepare``: ``reconstruct.data.prepare.prepare_video`` (the mediapipe detector in its own
  environment, as the command line's ``prepare``); it writes nothing unless every step succeeds;
* ``train on it``: the running trainer thread is stopped (a checkpoint first when it has a run
  folder, whose lock is then released), a new trainer is opened on the prepared scene in a run
  folder of its own (locked), and the app swaps it in on the GL thread.
Errors (no person found, unreadable file, a run folder in use) are kept as one line for the panel;
the running avatar is kept when anything fails."""

from __future__ import annotations

import dataclasses
import threading
from dataclasses import dataclass, field
from pathlib import Path

from .jobs import BackgroundJob

INPUT_HINT = "a video, an image (jpg/png/webp) or a folder of images"


def free_folder(base: Path) -> Path:
    """``base`` if it does not exist yet, else ``base-2``, ``base-3``, ..."""
    if not base.exists():
        return base
    k = 2
    while Path(f"{base}-{k}").exists():
        k += 1
    return Path(f"{base}-{k}")


@dataclass
class FootageState:
    """What the footage panel shows and edits."""

    source: str = ""  # the input path the user typed
    masks: str = ""  # the user's own person masks (a mask video, image or folder; empty: the segmenter's)
    person: int = 0  # 0: the largest, most central person; N: the N-th from the left
    scene_folder: str | None = None  # the prepared scene (after success)
    report_text: str | None = None
    report_image: str | None = None  # SCENE/prepare_report.png
    people_image: str | None = None  # SCENE/prepare_people.png: who is who, where several people were found
    message: str | None = None  # the last error, one line
    log: list[str] = field(default_factory=list)
    # (stage, done, total) of the step prepare is in, as it reports it (None: not known yet)
    step: tuple[str, int, int] | None = None
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def set_step(self, stage: str, done: int, total: int) -> None:
        with self._lock:
            self.step = (str(stage), int(done), int(total))

    def current_step(self) -> tuple[str, int, int] | None:
        with self._lock:
            return self.step

    def add_log(self, line: str) -> None:
        with self._lock:
            self.log.append(str(line))
            del self.log[:-12]

    def log_lines(self) -> list[str]:
        with self._lock:
            return list(self.log)


class FootageController:
    """The prepare and switch jobs of one studio window (``app`` is the StudioApp)."""

    def __init__(self, app, scenes_root: str | Path = "scenes", runs_root: str | Path = "runs") -> None:
        self.app = app
        self.state = FootageState()
        self.scenes_root = Path(scenes_root)
        self.runs_root = Path(runs_root)
        self.prepare_job: BackgroundJob | None = None
        self.switch_job: BackgroundJob | None = None
        self.fit_config = None  # reconstruct.data.prepare.FitConfig for prepare (None: its defaults)

    @property
    def busy(self) -> bool:
        """A job is running or its result has not been taken in yet (``poll``)."""
        return self.prepare_job is not None or self.switch_job is not None

    # ----- prepare ---------------------------------------------------------------------------
    def prepare(self, source: str | None = None, person: int | None = None) -> bool:
        """Start preparing ``source`` (default: the panel's path). False (with a message) when it
        cannot start: nothing given, no such file, or a job already running."""
        st = self.state
        source = (st.source if source is None else source).strip()
        person = st.person if person is None else person
        if self.busy:
            st.message = "a prepare or switch is already running"
            return False
        if not source:
            st.message = f"give {INPUT_HINT}"
            return False
        path = Path(source).expanduser()
        if not path.exists():
            st.message = f"{path}: no such file or folder ({INPUT_HINT} expected)"
            return False
        masks = Path(st.masks.strip()).expanduser() if st.masks.strip() else None
        if masks is not None and not masks.exists():
            st.message = f"{masks}: no such mask file or folder (a mask video, a mask image or a folder of them)"
            return False
        out = free_folder(Path(self.scenes_root) / (path.stem or "footage"))
        st.message = st.report_text = st.report_image = st.people_image = st.scene_folder = st.step = None
        st.log.clear()
        st.add_log(f"preparing {path} into {out}")

        def work():
            from reconstruct.data.prepare import MediapipeDetector, format_report, prepare_video

            Path(self.scenes_root).mkdir(parents=True, exist_ok=True)
            extra = {} if self.fit_config is None else {"fit_config": self.fit_config}
            folder, report = prepare_video(path, out, detector=MediapipeDetector(), person=person or None,
                                           masks=masks, log=st.add_log, progress=st.set_step, **extra)
            return folder, format_report(report)

        self.prepare_job = BackgroundJob(work, name="prepare")
        return True

    # ----- train on the prepared scene ------------------------------------------------------------
    def train_on(self, scene_folder: str | None = None) -> bool:
        """Stop the running training (checkpoint first) and train a new avatar on ``scene_folder``
        (default: the one just prepared) in a run folder of its own."""
        st = self.state
        folder = scene_folder or st.scene_folder
        if self.busy:
            st.message = "a prepare or switch is already running"
            return False
        if not folder:
            st.message = "prepare a video or image first"
            return False
        run_dir = free_folder(Path(self.runs_root) / Path(folder).name)
        app = self.app
        old_thread, old_lock = app.trainer, app.run_lock
        config = app.trainer.trainer.config

        def work():
            from reconstruct.run_folder import RunFolder

            run = RunFolder(run_dir)
            lock = run.lock()
            lock.__enter__()
            try:
                trainer = run.open(str(folder), dataclasses.replace(config, holdout=None), progress=False)
            except BaseException:
                lock.release()
                raise
            old_thread.stop(save=True)
            if old_lock is not None:
                old_lock.release()
            return trainer, run, lock

        st.add_log(f"training on {folder} in {run_dir}")
        self.switch_job = BackgroundJob(work, name="switch")
        return True

    # ----- GL thread, once per frame ----------------------------------------------------------------
    def poll(self) -> None:
        st = self.state
        job = self.prepare_job
        if job is not None and job.done:
            self.prepare_job = None
            if job.error:
                st.message = f"prepare failed: {job.error}"
                st.add_log(st.message)
            else:
                folder, text = job.result
                st.scene_folder, st.report_text = str(folder), text
                from reconstruct.data.prepare.report_image import PEOPLE_IMAGE, REPORT_IMAGE

                image, people = Path(folder) / REPORT_IMAGE, Path(folder) / PEOPLE_IMAGE
                st.report_image = str(image) if image.is_file() else None
                st.people_image = str(people) if people.is_file() else None
                st.add_log(f"wrote {folder} in {job.seconds:.0f} s")
        job = self.switch_job
        if job is not None and job.done:
            self.switch_job = None
            if job.error:
                st.message = f"could not start training: {job.error}"
                st.add_log(st.message)
            else:
                trainer, run, lock = job.result
                self.app.attach_trainer(trainer, run, lock)
