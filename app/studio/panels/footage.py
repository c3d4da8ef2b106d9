"""Footage panel: your own video, image or folder of images -> prepare (progress, report and
picture) -> train on it."""

from __future__ import annotations

import time

from imgui_bundle import imgui

from .common import error_text, wrapped_hint
from .context import PanelContext


def draw(ui: PanelContext) -> None:
    fc = ui.footage
    if fc is None:
        return
    st = fc.state
    wrapped_hint("A video, an image (jpg/png/webp) or a folder of images of one person, front view, whole body. "
                 "A cut-out (with transparency) is its own mask; other masks of yours go in 'masks'.")
    ch, text = imgui.input_text("file or folder", st.source)
    ui.mark("footage_path")
    if ch:
        st.source = text
    ch, text = imgui.input_text("masks (optional)", st.masks)
    if imgui.is_item_hovered():
        imgui.set_tooltip("your own person masks instead of the segmenter's: a mask video, a mask image or a\n"
                          "folder of them (white or opaque: person). A cut-out's transparency is used by itself.")
    if ch:
        st.masks = text
    ch, v = imgui.input_int("person (0 = auto)", st.person, 1, 1)
    if ch:
        st.person = max(0, v)
    imgui.begin_disabled(fc.busy)
    if imgui.button("Prepare"):
        fc.prepare()
    ui.mark("footage_prepare")
    imgui.same_line()
    imgui.begin_disabled(st.scene_folder is None)
    if imgui.button("Train on it"):
        fc.train_on()
    ui.mark("footage_train")
    imgui.end_disabled()
    imgui.end_disabled()
    if fc.busy:
        step = st.current_step() if fc.prepare_job else None
        if step is not None and step[2] > 0:
            from reconstruct.data.prepare.pipeline import STAGE_WORDS

            stage, done, total = step
            imgui.progress_bar(done / total, imgui.ImVec2(-1, 0), f"{STAGE_WORDS.get(stage, stage)} {done}/{total}")
        else:  # no step count yet (reading the input), or switching: an animated bar
            phase = (time.perf_counter() * 0.5) % 1.0
            imgui.progress_bar(-phase, imgui.ImVec2(-1, 0), "preparing..." if fc.prepare_job else "switching...")
    for line in st.log_lines()[-5:]:
        imgui.text_disabled(line[-70:])
    if st.report_text:
        if imgui.tree_node("report"):
            imgui.text_unformatted(st.report_text)
            imgui.tree_pop()
    if st.people_image:
        imgui.set_next_item_open(True, imgui.Cond_.once)
        if imgui.tree_node("who is who (person N)"):
            _picture(ui, st.people_image)
            imgui.tree_pop()
    if st.report_image:
        _picture(ui, st.report_image)
    if st.message:
        error_text(st.message)


def _picture(ui: PanelContext, path: str) -> None:
    """An image file as wide as the panel."""
    tex = ui.texture(path)
    if tex is not None:
        w = imgui.get_content_region_avail().x
        tw, th = tex.size
        imgui.image(imgui.ImTextureRef(tex.glo), imgui.ImVec2(w, w * th / max(tw, 1)))
