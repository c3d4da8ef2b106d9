"""The headless demo: load the built-in scene and write its contact sheet."""

from __future__ import annotations

import time
from pathlib import Path

import torch

from app.contact_sheet import write_contact_sheet
from reconstruct.data.load import load_scene


def run_demo(spec: str, out: Path, *, threads: int | None = None) -> int:
    if threads:
        torch.set_num_threads(threads)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    scene = load_scene(spec)
    print(scene.summary())
    print(f"contact sheet: {write_contact_sheet(scene, out / 'contact_sheet.png')} ({time.time() - t0:.0f} s)")
    return 0
