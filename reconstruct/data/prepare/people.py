"""Which person to prepare when a frame shows several: number them left to right, pick one (the largest
and most central by default, or ``--person N``), follow them through the frames, and give the box that
holds them in every frame."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .detector import PersonCandidate


class PersonChoiceError(ValueError):
    """``--person N`` asked for someone who is not there."""


@dataclass
class PersonTrack:
    """The chosen person: ``index`` (1-based, left to right in the first frame with people), how many
    were found there, and per frame their candidate (None where they were not found)."""

    index: int
    count: int
    picked_by: str  # "auto" or "--person"
    per_frame: list[PersonCandidate | None]
    others: list[list[PersonCandidate]]  # per frame everyone else

    @property
    def first(self) -> int:
        """The first frame (of those searched) where the chosen person was found: where they are numbered."""
        return next(i for i, c in enumerate(self.per_frame) if c is not None)

    @property
    def choice(self) -> str:
        """How the person was chosen, in words for the log."""
        return "largest and most central" if self.picked_by == "auto" else "--person"

    def union_box(self) -> tuple[float, float, float, float] | None:
        boxes = [c.box for c in self.per_frame if c is not None]
        if not boxes:
            return None
        b = np.asarray(boxes)
        return float(b[:, 0].min()), float(b[:, 1].min()), float(b[:, 2].max()), float(b[:, 3].max())


def auto_score(c: PersonCandidate, width: int, height: int) -> float:
    """Large and central: the person's height times a penalty for distance from the image centre."""
    cx, cy = c.center
    d = np.hypot((cx - width / 2) / width, (cy - height / 2) / height) / np.hypot(0.5, 0.5)
    return c.height * (1.0 - 0.6 * d)


def choose_person(people: list[list[PersonCandidate]], width: int, height: int,
                  person: int | None = None, source: str = "the input") -> PersonTrack | None:
    """Pick a person in the first frame that has people and follow them (nearest box centre, scaled by
    size) through the others. None when nobody was found anywhere."""
    first = next((i for i, f in enumerate(people) if f), None)
    if first is None:
        return None
    ordered = sorted(people[first], key=lambda c: c.center[0])
    if person is not None:
        if not 1 <= person <= len(ordered):
            raise PersonChoiceError(f"{source}: --person {person} asked for, but {len(ordered)} "
                                    f"{'person was' if len(ordered) == 1 else 'people were'} found (numbered 1 to "
                                    f"{len(ordered)} from left to right)")
        k, how = person - 1, "--person"
    else:
        k, how = int(np.argmax([auto_score(c, width, height) for c in ordered])), "auto"
    per_frame: list[PersonCandidate | None] = [None] * len(people)
    others: list[list[PersonCandidate]] = [list(f) for f in people]
    per_frame[first] = ordered[k]
    others[first] = [c for j, c in enumerate(ordered) if j != k]
    for step in (1, -1):
        prev = ordered[k]
        i = first + step
        while 0 <= i < len(people):
            if people[i]:
                dist = [np.hypot(c.center[0] - prev.center[0], c.center[1] - prev.center[1]) / max(prev.height, 1.0)
                        for c in people[i]]
                j = int(np.argmin(dist))
                if dist[j] < 0.5:
                    per_frame[i] = people[i][j]
                    others[i] = [c for m, c in enumerate(people[i]) if m != j]
                    prev = people[i][j]
            i += step
    return PersonTrack(k + 1, len(ordered), how, per_frame, others)


TURN_AT_DEG = 60.0  # a person turned at least this far from upright in the frames is read turned
# the frames must agree on it: the length of the mean of their unit body directions (a cartwheel,
# whose directions cancel out, is kept as it is)
MIN_AGREEMENT = 0.7
_SHOULDERS, _HIPS = (11, 12), (23, 24)  # mediapipe's landmark indices


def quarter_turns(track: PersonTrack, *, min_visibility: float = 0.5) -> tuple[int, float]:
    """(k, angle): how the chosen person stands in the frames. ``angle`` is the degrees their body
    (hips -> shoulders, averaged as unit vectors over the frames that show both pairs) is turned
    from the image's up, clockwise positive; ``k`` the quarter turns counter-clockwise
    (``np.rot90(frame, k)``) that stand them up when it is at least ``TURN_AT_DEG`` and the frames
    agree on it (``MIN_AGREEMENT``), else 0 (a lean, a dance, a cartwheel: kept as they are). For a
    photo stored sideways without an orientation tag, a clip from a camera mounted on its side, a
    picture upside down."""
    ups = []
    idx = list(_SHOULDERS + _HIPS)
    for c in track.per_frame:
        if c is None:
            continue
        if (c.visibility[idx] < min_visibility).any():
            continue
        up = c.keypoints[list(_SHOULDERS)].mean(0) - c.keypoints[list(_HIPS)].mean(0)
        n = float(np.hypot(*up))
        if n > 0:
            ups.append(up / n)
    if not ups:
        return 0, 0.0
    x, y = np.mean(ups, axis=0)
    angle = float(np.degrees(np.arctan2(x, -y)))  # 0: head up; 90: head to the right; 180: upside down
    if abs(angle) < TURN_AT_DEG or np.hypot(x, y) < MIN_AGREEMENT:
        return 0, angle
    return int(round(angle / 90.0)) % 4, angle
