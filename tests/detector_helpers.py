"""The mediapipe detector for the prepare tests: its interpreter, or None where it is not installed
(a test failure instead when WONDERHUMAN_REQUIRE_DETECTOR=1, as in CI)."""

from __future__ import annotations

import os

import pytest

from reconstruct.data.prepare.detector import DetectorError, find_detector_python


def detector_python() -> str | None:
    try:
        return find_detector_python()[0]
    except DetectorError as exc:
        if os.environ.get("WONDERHUMAN_REQUIRE_DETECTOR") == "1":
            pytest.fail(f"WONDERHUMAN_REQUIRE_DETECTOR=1 but no detector: {exc}")
        return None
