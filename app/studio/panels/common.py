"""Drawing helpers shared by the panels."""

from __future__ import annotations

import numpy as np
from imgui_bundle import imgui, implot

PLOT_HEIGHT = 95
ERROR_RGBA = (1.0, 0.45, 0.4, 1.0)


def finite_xy(xs, ys) -> tuple[np.ndarray, np.ndarray]:
    x = np.asarray(xs, np.float64)
    y = np.asarray(ys, np.float64)
    ok = np.isfinite(x) & np.isfinite(y)
    return np.ascontiguousarray(x[ok]), np.ascontiguousarray(y[ok])


def error_text(text: str) -> None:
    imgui.push_text_wrap_pos(0.0)
    imgui.text_colored(imgui.ImVec4(*ERROR_RGBA), text)
    imgui.pop_text_wrap_pos()


def wrapped_hint(text: str) -> None:
    imgui.push_text_wrap_pos(0.0)
    imgui.text_disabled(text)
    imgui.pop_text_wrap_pos()


def plot(title: str, y_label: str, series: list[tuple[str, np.ndarray, np.ndarray]], width: float,
         marker: float | None = None) -> None:
    """One implot plot of ``series`` (label, x, y); axes fit the data each frame."""
    flags = implot.Flags_.no_menus.value | implot.Flags_.no_box_select.value
    if len(series) == 1:
        flags |= implot.Flags_.no_legend.value
    if implot.begin_plot(title, imgui.ImVec2(width, PLOT_HEIGHT), flags):
        fit = implot.AxisFlags_.auto_fit.value
        implot.setup_axes("", y_label, fit, fit)
        implot.setup_legend(implot.Location_.north_east.value)
        for label, x, y in series:
            if len(x):
                implot.plot_line(label, x, y)
        if marker is not None:
            implot.plot_inf_lines("##now", np.asarray([marker], np.float64))
        implot.end_plot()
