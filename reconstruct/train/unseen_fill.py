"""Stage I's last act: the Gaussians no training view ever saw take the wrap-around fill's colour
of the seen surface (``reconstruct.appearance.wrap_fill``), instead of whatever the decoder
extrapolates to texels it was never trained on.

Why. Flat discs that cover the surface without gaps (the Stage I fidelity work) leave the
unseen side with no gradient at all: its colour is the decoder's answer for untrained features,
a flat grey-mauve on the garment benchmark (`docs/stage1_fidelity.md`). The earlier layout's back
was trained, by accident, through the holes in its front and so took the front's garment colours.
The fill does on purpose what those holes did by accident, with the rules of the built-in prior:
each garment's colours all round, not the front's emblem or face.

How. The colour a Gaussian renders is ``sigmoid(decoded logit + gain * residual)``. For every
never-seen Gaussian the residual is set so that it decodes to its fill colour; nothing else
changes (seen Gaussians, geometry, the decoder). The sources are the seen flags eroded by
``erosion`` texels (Stage II's trusted flags): the last seen ring round the unseen side is the
silhouette at grazing incidence, darkened by its blend with the background. Painted visibility
(edits) counts: a region painted seen is not filled, one painted unseen is.

A garment layer's Gaussians are filled like the body's: they are one more part ("garment") whose
seen ones colour the unseen ones round the tube at the same height (the fill's band), eroded and
smoothed over the layer's own grid (``AvatarModel.neighbours``).

A garment layer's opacity is learned (its Gaussians may be cloth or empty air), but only where
training saw the layer: the back of a skirt kept its initial 0.5 and rendered half transparent
from behind, the legs showing through. ``fill_unseen_layer_opacity`` gives every layer Gaussian
that never faced a training camera (``layer_faced_training``; not the seen flags: a Gaussian the
alpha loss made transparent, below the hem or in a coat's opening, is no first hit and so not
"seen", yet its opacity is trained) the median opacity of the trained ones in its row of the
layer's grid (the same height round the tube; the nearest row with any where a row has none):
cloth seen at the front at a height is cloth at the back at that height, and rows the front made
empty (past the hem) stay empty.

A layer Gaussian seen only from inside the garment (through a coat's open front: its surface
faced no training camera, ``layer_seen_inside``) is unseen before the fill: its one colour is the
lining's, which from outside drew a dark patch on the back.

Stage II starts from this avatar and recomputes its own pseudo-colours from the same trusted
seen Gaussians, so the fill changes where Stage II starts, not where it is pulled to."""

from __future__ import annotations

from dataclasses import dataclass

from typing import TYPE_CHECKING

import numpy as np
import torch
from scipy.ndimage import binary_dilation

from ..appearance.cut_fill import FrameView, cut_colors
from ..appearance.gap_fill import enclosed_gap_colors
from ..appearance.occluded_fill import occluded_colors
from ..appearance.propagation import erode, erode_by_part
from ..appearance.wrap_fill import WrapFillConfig, long_hair_colors, wrap_fill_colors
from ..avatar.garment_layer import spread_frames
from ..avatar.layer_cover import model_body_under_layer
from ..avatar.layer_through import model_layer_behind_limbs, model_layer_shows_body, model_layer_shows_limbs
from ..avatar.limbs_over_cloth import model_limbs_over_cloth

if TYPE_CHECKING:
    from ..avatar.state import AvatarState
    from .data import TrainingData

# target colours are kept this far inside (0, 1) so that their logits stay finite
_COLOR_MARGIN = 1e-3

# a gap's colour read along its row or column (``appearance.gap_fill``) is taken where no channel is
# further than this from the row's colour the wrap fill gives it
_GAP_TOLERANCE = 0.3


@torch.no_grad()
def fill_unseen_colors(state: AvatarState, *, erosion: int = 2, keep_ring: int = 0, grazing_rule: bool = True,
                       not_sources: torch.Tensor | None = None, ring_trained: torch.Tensor | None = None,
                       hair_views=None, layer_gaps: torch.Tensor | None = None, layer_gap_reach: int = 16) -> int:
    """Set the colour residual of every Gaussian the painted seen flags call unseen so that it
    decodes to the wrap-around fill's colour. Returns how many Gaussians were filled (0 when the
    avatar has no colour residual, sees nothing or sees everything). ``grazing_rule``: seen
    Gaussians seen at grazing incidence only are no colour source (``WrapFillConfig.max_seen_angle_deg``;
    for avatars trained on one fixed background, whose silhouette colours are darkened by it).
    ``not_sources``: (N,) bool, seen Gaussians that keep their colour but are no colour source
    either (those seen by their blend weight alone, ``SeenRecount.blended_only``: many sit at the
    silhouette, where a photo's matting leaves a light fringe). ``ring_trained``: (N+M,) bool, the
    Gaussians whose decoded colour the training images shaped; an unseen one of the ``keep_ring``
    that is not among them is filled too (None: the ring keeps every decoded colour). ``hair_views``:
    the training frames in which hair worn down is read (``hair_views_of``): its colours are kept
    as ``state.hair_colors`` for the fills after this one (None: the state's are used as they are).
    ``layer_gaps``: (N+M,) bool, unseen garment-layer Gaussians inside the seen cloth (those the
    arms hid): where trusted cloth lies within ``layer_gap_reach`` grid steps both ways along their
    row or their column they take the colours read along it (``appearance.gap_fill``) instead of
    their row's, where those lie within ``_GAP_TOLERANCE`` of it (None or a reach of 0: the row's)."""
    model = state.model
    cfg = model.config
    if not cfg.color_residual:
        return 0
    seen = state.edits.paint(state.seen).cpu().bool()
    unseen = ~seen
    if not bool(seen.any()) or not bool(unseen.any()):
        return 0
    neighbours = model.neighbours()  # a garment layer's Gaussians over its own grid, one more part
    sources = seen if not_sources is None else seen & ~torch.as_tensor(not_sources, dtype=torch.bool).cpu()
    if not bool(sources.any()):
        sources = seen
    trusted = torch.as_tensor(erode_by_part(sources.numpy(), neighbours, model.parts(), erosion))
    if not bool(trusted.any()):
        trusted = sources
    colors = model.canonical(None).colors.detach().cpu()
    normals = model.base_normals.cpu() if grazing_rule else None
    under = model_body_under_layer(model)
    hair_seen = torch.as_tensor(erode(sources.numpy(), neighbours, min(erosion, 1)))
    if hair_views is not None:
        state.hair_colors = long_hair_colors(model.base_positions.cpu(), model.parts(), trusted, colors, hair_views,
                                             neighbours, normals=normals, under_layer=under, hair_seen=hair_seen,
                                             surface_normals=model.base_normals.cpu())
    filled = wrap_fill_colors(model.base_positions.cpu(), model.parts(), trusted, colors, neighbours,
                              normals=normals, no_mirror=state.edits.redone, under_layer=under,
                              layer_grid=model.layer_grid(), hair_seen=hair_seen,
                              surface_normals=model.base_normals.cpu(), cut_colors=state.cut_colors,
                              row_seen=sources, occluded_colors=state.occluded_colors, hair_colors=state.hair_colors)
    if layer_gaps is not None and layer_gap_reach and model.layer is not None and model.num_layer:
        nb = model.num_body
        gap_flags = torch.as_tensor(layer_gaps, dtype=torch.bool).cpu()
        if tuple(gap_flags.shape) != tuple(unseen.shape):
            raise ValueError(f"fill_unseen_colors: layer_gaps must have shape {tuple(unseen.shape)} (one flag per "
                             f"Gaussian), found {tuple(gap_flags.shape)}")
        gap_colors = enclosed_gap_colors(model.layer.grid_neighbours(), trusted[nb:].numpy(),
                                         colors[nb:].double().numpy(), (unseen & gap_flags)[nb:].numpy(),
                                         reach=layer_gap_reach)
        filled = torch.as_tensor(filled).clone()
        # read along the row or column, but near the row's colour: a gap in an open coat's flap has
        # the shirt beside it in the row, and its colour is no cloth's
        near = np.abs(gap_colors - filled[nb:].double().numpy()).max(1) <= _GAP_TOLERANCE
        take = np.isfinite(gap_colors).all(1) & near
        filled[nb:][torch.as_tensor(take)] = torch.as_tensor(gap_colors[take], dtype=filled.dtype)
    todo = torch.as_tensor(erode(unseen.numpy(), neighbours, keep_ring)) if keep_ring else unseen
    if ring_trained is not None:
        ring_trained = torch.as_tensor(ring_trained, dtype=torch.bool).cpu()
        if tuple(ring_trained.shape) != tuple(unseen.shape):
            raise ValueError(f"fill_unseen_colors: ring_trained must have shape {tuple(unseen.shape)} (one flag per "
                             f"Gaussian), found {tuple(ring_trained.shape)}")
        todo = todo | (unseen & ~ring_trained)
    idx = torch.nonzero(todo).squeeze(1)
    decoded_logit = model.decode_raw(None, None)["color"].detach().cpu()[idx]
    target = torch.logit(filled[idx].to(decoded_logit.dtype).clamp(_COLOR_MARGIN, 1 - _COLOR_MARGIN))
    residual = model.decoder.color_residual
    residual.data[idx.to(residual.device)] = ((target - decoded_logit) / cfg.color_residual_gain).to(
        residual.device, residual.dtype)
    return int(len(idx))


def _frame_views(state: AvatarState, data: TrainingData, frames=None):
    """The training frames (``frames``, or all) as ``appearance.cut_fill.FrameView``s, each posed
    when it is read (the frame's whole image, not the crop training works on)."""
    for i in data.frames if frames is None else frames:
        f = data.scene.frames[i]
        uv, z = f.camera.project(state.posed(i).means.detach().cpu().double().numpy())
        yield FrameView(uv, z > 0, f.image, f.mask)


def hair_views_of(state: AvatarState, data: TrainingData, max_frames: int = 8):
    """The training frames the wrap fill reads hair worn down in (``appearance.long_hair``): up to
    ``max_frames`` spread over the sequence, each posed when it is read."""
    return _frame_views(state, data, spread_frames(list(data.frames), max_frames))


@torch.no_grad()
def out_of_view(state: AvatarState, data: TrainingData) -> torch.Tensor:
    """(N+M,) bool: the Gaussians whose posed centre lies in no training frame's image (outside it,
    or behind its camera, in every frame): past the edges of a photo that cuts the person off."""
    inside = np.zeros(state.model.num_gaussians, bool)
    for view in _frame_views(state, data):
        inside |= view.inside()
    return torch.as_tensor(~inside)


# pixels (a share of the image's longer side) from an edge within which the images show what a limb
# wears where it crosses the edge (``prepare``'s landmarks at a cut edge use the same reach)
CUT_EDGE_SHARE = 0.02


@torch.no_grad()
def cut_colors_of(state: AvatarState, data: TrainingData, *, edge_share: float = CUT_EDGE_SHARE) -> torch.Tensor:
    """(N+M,3) float32: ``appearance.cut_fill.cut_colors`` for the Gaussians ``out_of_view``, read
    on every training frame's whole image within ``edge_share`` of its longer side of the edges; NaN
    for the others (all NaN when the whole person is in view: the frames are then posed once).
    Otherwise each frame is posed a second time for the colours rather than every frame's
    projections held at once (about 1 MB a frame on a 60k-Gaussian avatar; a long video's frames
    would hold hundreds)."""
    beyond = out_of_view(state, data).numpy()
    if not beyond.any():
        return torch.full((len(beyond), 3), float("nan"))
    cam = data.scene.frames[data.frames[0]].camera
    return torch.as_tensor(cut_colors(state.model.parts(), beyond, _frame_views(state, data),
                                      edge_px=edge_share * max(cam.width, cam.height)))


@torch.no_grad()
def occluded_colors_of(state: AvatarState, data: TrainingData, *,
                       parts: tuple[str, ...] = WrapFillConfig.occluded_parts,
                       max_frames: int = 16) -> torch.Tensor:
    """(N+M,3) float32: ``appearance.occluded_fill.occluded_colors`` for the Gaussians of ``parts``
    on up to ``max_frames`` training frames spread over the sequence (each frame's whole image; the
    surface normals posed with the frame), NaN for the others."""
    def views():
        for i in spread_frames(list(data.frames), max_frames):
            f = data.scene.frames[i]
            posed, normals = state.posed_with_surface_normals(i)
            means = posed.means.detach().cpu().double()
            uv, z = f.camera.project(means.numpy())
            to_cam = torch.as_tensor(f.camera.center, dtype=means.dtype) - means
            cos = (to_cam * normals.detach().cpu().double()).sum(1) / to_cam.norm(dim=1).clamp_min(1e-9)
            yield FrameView(uv, z > 0, f.image, f.mask), cos.numpy()
    return torch.as_tensor(occluded_colors(state.model.parts(), views(), part_names=parts))


@dataclass(frozen=True)
class LimbViews:
    """What the garment layer's arm rules (``layer_through``, ``layer_behind_limbs``,
    ``limbs_over_cloth``) read, made once for all three: the training frames posed, and the
    canonical colours (which the rules do not change; the seen flags they do, so those are read by
    each rule)."""
    frames: list  # (camera, posed means (N+M,3) float64) of the training frames read
    colors: torch.Tensor  # (N+M,3) canonical colours, on the CPU


@torch.no_grad()
def limb_views(state: AvatarState, data: TrainingData, max_frames: int = 8) -> LimbViews:
    """``LimbViews`` of up to ``max_frames`` training frames spread over the sequence."""
    frames = [(data.targets[i].camera, state.posed(i).means.detach().cpu().double().numpy())
              for i in spread_frames(list(data.frames), max_frames)]
    return LimbViews(frames, state.model.canonical(None).colors.detach().cpu())


def layer_through(state: AvatarState, data: TrainingData | None = None, max_frames: int = 8,
                  views: LimbViews | None = None) -> torch.Tensor | None:
    """(N+M,) bool: the seen garment-layer Gaussians that show the body, not cloth
    (``avatar.layer_through``): under its hem, and, given the training ``data`` (or their
    ``limb_views``), in front of an arm or a hand in up to ``max_frames`` of its frames; from the
    painted seen flags and the canonical colours. None without a layer."""
    model = state.model
    if model.layer is None or model.num_layer == 0:
        return None
    if views is None and data is not None and len(data.frames):
        views = limb_views(state, data, max_frames)
    seen = state.edits.paint(state.seen).cpu().bool()
    colors = model.canonical(None).colors.detach().cpu() if views is None else views.colors
    flags = model_layer_shows_body(model, seen, colors)
    if views is not None and views.frames:
        flags = flags | model_layer_shows_limbs(model, seen, colors, views.frames)
    return torch.as_tensor(flags)


def layer_behind_limbs(state: AvatarState, data: TrainingData, max_frames: int = 8,
                       views: LimbViews | None = None) -> torch.Tensor | None:
    """(N+M,) bool: the seen garment-layer Gaussians that lie behind an arm or a hand in one of up to
    ``max_frames`` of the training frames (or their ``limb_views``) and took its colour
    (``avatar.layer_through``, "Behind an arm"); from the painted seen flags and the canonical
    colours. None without a layer."""
    return _arm_rule(model_layer_behind_limbs, state, data, max_frames, views)


def limbs_over_cloth(state: AvatarState, data: TrainingData, max_frames: int = 8,
                     views: LimbViews | None = None) -> torch.Tensor | None:
    """(N+M,) bool: the seen arm and hand Gaussians that lie by the garment layer in one of up to
    ``max_frames`` of the training frames (or their ``limb_views``) and took the cloth's colour
    (``avatar.limbs_over_cloth``); from the painted seen flags and the canonical colours. None
    without a layer."""
    return _arm_rule(model_limbs_over_cloth, state, data, max_frames, views)


def _arm_rule(rule, state: AvatarState, data: TrainingData, max_frames: int, views: LimbViews | None):
    """``rule(model, seen, colors, frames)`` (a model-level arm rule) on the painted seen flags and
    the training frames' ``limb_views``, as a tensor; None without a layer."""
    model = state.model
    if model.layer is None or model.num_layer == 0 or not len(data.frames):
        return None
    views = limb_views(state, data, max_frames) if views is None else views
    seen = state.edits.paint(state.seen).cpu().bool()
    return torch.as_tensor(rule(model, seen, views.colors, views.frames))


# layer opacities are set this far inside (0, 1) so that their logits stay finite
_OPACITY_MARGIN = 1e-3
# a row of the layer whose trained Gaussians' median opacity is below this is empty air
_EMPTY_LAYER_OPACITY = 0.1
_HEM_RUN = 0.03  # metres under a hem row whose trained cloth must all be below one half
# metres of rows at least one half opaque, one after another, below a low band that make it a band
# of the cloth (a hand at the waist), not the hem
_CLOTH_RUN = 0.05


def _in_some_frame(state: AvatarState, data: TrainingData, flags: dict) -> dict[str, torch.Tensor]:
    """{name: (M,) bool}: for each of ``flags`` ({name: (flag, surface)}), the garment-layer
    Gaussians for which ``flag(means, normals, target)`` ((M,) bool from the frame's posed layer
    Gaussians and its ``FrameTarget``) holds in some training frame. ``normals``: the learned ones,
    posed; with ``surface``, the layer's own surface normals, posed
    (``AvatarState.posed_with_surface_normals``). One pass over the frames poses each once."""
    model = state.model
    N, M = model.num_body, model.num_layer
    out = {name: torch.zeros(M, dtype=torch.bool) for name in flags}
    if M == 0:
        return out
    surface = any(on_surface for _, on_surface in flags.values())
    with torch.no_grad():
        for i in data.frames:
            posed, surface_normals = state.posed_with_surface_normals(i, surface=surface)
            means = posed.means[N:].detach()
            for name, (flag, on_surface) in flags.items():
                normals = surface_normals if on_surface else posed.normals
                out[name] |= torch.as_tensor(flag(means, normals[N:].detach(), data.targets[i])).cpu()
    return out


def _facing(min_cos: float):
    """The ``flag`` of ``_in_some_frame`` that holds where the cosine between the normal and the
    direction to the frame's camera is at least ``min_cos``."""
    def faced(means, normals, target):
        to_cam = torch.as_tensor(target.camera.center, dtype=means.dtype, device=means.device) - means
        return (to_cam * normals).sum(1) / to_cam.norm(dim=1).clamp_min(1e-9) >= min_cos
    return faced


def _off_person(margin: int):
    """The ``flag`` of ``_in_some_frame`` that holds where the posed centre lands on the background
    (``layer_off_person``)."""
    def off(means, normals, target):
        mask = target.mask.cpu().numpy() > 0.5
        if margin > 0:
            mask = binary_dilation(mask, iterations=margin)
        h, w = mask.shape
        uv, z = target.camera.project(means.cpu().double().numpy())
        u, v = np.floor(uv[:, 0]).astype(np.int64), np.floor(uv[:, 1]).astype(np.int64)
        inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
        on = np.zeros(len(u), bool)
        on[inside] = mask[v[inside], u[inside]]
        return (z > 0) & ~on
    return off


_FACED_MIN_COS = 0.2
_OFF_PERSON_MARGIN = 2
_SURFACE_FACED = (_facing(0.0), True)  # the layer's own surface faced the camera (``layer_seen_inside``)


def layer_faced_training(state: AvatarState, data: TrainingData, *, min_cos: float = _FACED_MIN_COS) -> torch.Tensor:
    """(M,) bool: the garment-layer Gaussians that faced a training camera in some frame (the cosine
    between the posed normal and the direction to the camera at least ``min_cos``): those whose
    opacity training could have set, opaque cloth or empty air (a Gaussian the alpha loss made
    transparent is no first hit, so the seen flags cannot tell it from one never trained)."""
    return _in_some_frame(state, data, {"faced": (_facing(min_cos), False)})["faced"]


def layer_seen_inside(state: AvatarState, data: TrainingData) -> torch.Tensor:
    """(M,) bool: the seen garment-layer Gaussians (``state.seen``) whose surface (the layer's own
    normal, posed: ``posed_with_surface_normals``, not the learned one, which a normal map of the
    lining turns towards the camera) faced no training camera in any frame: seen from inside the
    garment, through an opening, so their colour is the inside's."""
    return _seen_inside(state, _in_some_frame(state, data, {"surface": _SURFACE_FACED})["surface"])


def _seen_inside(state: AvatarState, surface_faced: torch.Tensor) -> torch.Tensor:
    """``layer_seen_inside`` from ``surface_faced``, the (M,) layer Gaussians whose own surface faced
    some training camera."""
    return state.seen.cpu().bool()[state.model.num_body:] & ~surface_faced


def layer_off_person(state: AvatarState, data: TrainingData, *, margin: int = _OFF_PERSON_MARGIN) -> torch.Tensor:
    """(M,) bool: the garment-layer Gaussians whose posed centre lands on the background in some
    training frame: in front of the camera, and outside the frame's crop or more than ``margin``
    pixels off its mask. Nothing opaque can stand between such a Gaussian and the camera (the
    mask is empty there), so the frame shows it is empty air, whichever way its normal faces:
    the rings of a layer stretched sideways for a flap, seen edge-on past the flap's outer end."""
    return _in_some_frame(state, data, {"off": (_off_person(margin), False)})["off"]


def layer_training_views(state: AvatarState, data: TrainingData, *, seen_inside: bool,
                         off_person: bool) -> dict[str, torch.Tensor]:
    """What the finish reads from the training frames about the garment layer, in one pass over
    them: ``faced`` (``layer_faced_training``), and with the switches ``seen_inside``
    (``layer_seen_inside``) and ``off_person`` (``layer_off_person``); (M,) bool each."""
    flags = {"faced": (_facing(_FACED_MIN_COS), False)}
    if seen_inside:
        flags["surface"] = _SURFACE_FACED
    if off_person:
        flags["off_person"] = (_off_person(_OFF_PERSON_MARGIN), False)
    out = _in_some_frame(state, data, flags)
    if seen_inside:
        out["seen_inside"] = _seen_inside(state, out.pop("surface"))
    return out


def mark_outline_cut(state: AvatarState, off_person: torch.Tensor, min_opacity: float = 0.5) -> int:
    """Record in the model (``AvatarModel.mark_outline_cut``) the garment layer's Gaussians the
    person's outline cut away: on the background in some training frame (``off_person``, (M,) bool,
    ``layer_off_person``) and made transparent by training (opacity under ``min_opacity``), not
    trimmed. ``layer_cover`` counts them as the cloth's. Returns how many; 0 without a layer."""
    model = state.model
    if model.layer is None or model.num_layer == 0:
        return 0
    opacity = model.opacities().detach().cpu()[model.num_body:]
    cut = off_person.cpu().bool() & (opacity < min_opacity) & ~model.layer_trimmed.cpu()
    return model.mark_outline_cut(cut)


def layer_reached(state: AvatarState, total_max: torch.Tensor, min_weight: float) -> torch.Tensor:
    """(M,) bool: the garment-layer Gaussians the training rays reached: their blend weight in one
    training frame (``PersonCoverage.total_max``, all N+M Gaussians), divided by their opacity, is
    at least ``min_weight`` pixels. Weight over opacity is the sum of transmittance times footprint,
    what the Gaussian would blend were it opaque: a Gaussian training made transparent in front of
    the person or off it is reached (its opacity was set), one behind opaque cloth is not. Unlike
    ``layer_faced_training`` it does not read the learned normals, which turn freely where no
    normal maps pin them (one photo: 501 of 4,048 layer Gaussians faced the camera).
    (Alpha is clamped at 0.99 in the rasterizer; the reach of a nearly opaque Gaussian is read a
    little low, never high.)"""
    model = state.model
    N = model.num_body
    if model.layer is None:
        return torch.zeros(0, dtype=torch.bool)
    opacity = model.opacities().detach().cpu().double()[N:]
    return (total_max[N:].double() / opacity.clamp_min(1e-6)) >= min_weight


@torch.no_grad()
def fill_unseen_layer_opacity(state: AvatarState, trained: torch.Tensor, *, erosion: int = 2,
                              empty: torch.Tensor | None = None) -> int:
    """Give every garment-layer Gaussian that is not ``trained`` ((M,) bool, ``layer_faced_training``),
    not ``empty`` ((M,) bool, ``layer_off_person``: a training frame shows background where it
    stands; it keeps its learned opacity) and not painted seen the median opacity of the trained
    ones (eroded by ``erosion`` grid steps) in its grid row, or in the nearest row that has any;
    below the hem (the first row under the most opaque one with a median below 0.5 whose next row
    and rows 3 cm under it are too, and under which no 5 cm of rows are 0.5 or more) those medians
    are made non-increasing down the rows (no ring of cloth below the hem), a row above it below 0.5
    takes the lower of the most opaque rows above and below it (cloth behind a hand), and medians
    below 0.1 (cloth the alpha loss was emptying) are 0. Returns how many were set (0 without a layer, or when none or all are trained)."""
    model = state.model
    if model.layer is None:
        return 0
    N = model.num_body
    trained = torch.as_tensor(trained, dtype=torch.bool).cpu()
    if trained.shape != (model.num_layer,):
        raise ValueError(f"fill_unseen_layer_opacity: trained flags must have shape ({model.num_layer},), "
                         f"found {tuple(trained.shape)}")
    todo = ~trained & ~state.edits.paint(state.seen).cpu().bool()[N:]
    if empty is not None:
        empty = torch.as_tensor(empty, dtype=torch.bool).cpu()
        if empty.shape != (model.num_layer,):
            raise ValueError(f"fill_unseen_layer_opacity: empty flags must have shape ({model.num_layer},), "
                             f"found {tuple(empty.shape)}")
        todo &= ~empty
    full = torch.ones(model.num_gaussians, dtype=torch.bool)
    full[N:] = trained
    sources = torch.as_tensor(erode(full.numpy(), model.neighbours(), erosion))[N:]
    if not bool(sources.any()):
        sources = trained
    if not bool(sources.any()) or not bool(todo.any()):
        return 0
    rows = model.layer_rc[:, 0].cpu()
    opacity = model.opacities().detach().cpu()[N:]
    R = model.layer.grid_shape[0]
    have = [r for r in range(R) if bool(sources[rows == r].any())]
    per_row = torch.empty(R, dtype=opacity.dtype)
    for r in range(R):
        near = min(have, key=lambda h: (abs(h - r), h))
        per_row[r] = opacity[(rows == near) & sources].median()
    # cloth hangs from its top: below the hem (rows run down from the top) no row is more opaque
    # than the one above it. Where the hem is curved the trained rows near it mix opaque and
    # emptied columns and their medians jump: on the coat photo a row 2 cm below the hem took 0.19
    # between rows of 0.04-0.09, a ring hanging under the back of the coat. (Above the hem the
    # medians' small ups and downs, 0.90-1.00 on coat seed 2, are the cloth's and stay.) The hem
    # is the first row under the most opaque one below one half whose next row and rows within
    # ``_HEM_RUN`` under it are below one half too: on the grey-skirt photo a single row at the
    # waist, its front under the hand, took 0.37 from 9 Gaussians, and as the hem it emptied the
    # skirt's whole back below it. Nor is a low band the hem when ``_CLOTH_RUN`` of opaque rows
    # follow it: the same photo turned by 9 degrees had eight low rows at the waist (11 cm, under
    # the hand and her clutch) above 34 cm of opaque skirt.
    top = int(per_row.argmax())
    zs = model.layer.positions.reshape(R, -1, 3)[:, :, 2].double().mean(1)
    low = per_row < 0.5

    # the last row of the lowest run of opaque rows at least ``_CLOTH_RUN`` tall: the hem is under it
    cloth_end, start = -1, None
    for k in range(R):
        if low[k]:
            start = None
        else:
            start = k if start is None else start
            if zs[start] - zs[k] >= _CLOTH_RUN:
                cloth_end = k

    def hem_like(r: int) -> bool:
        under = (zs[r] - zs[r:] <= _HEM_RUN) | (torch.arange(r, R) <= r + 1)
        return bool(low[r:][under].all())

    hem = next((r for r in range(max(top, cloth_end + 1), R) if hem_like(r)), None)
    if hem is not None:
        per_row[hem:] = torch.cummin(per_row[hem:], 0).values
    # A row above the hem below one half between more opaque ones (a hand or an arm in front of
    # the cloth there) is cloth like its neighbours: it takes the lower of the most opaque rows
    # above it and below it, down to the hem.
    cloth = per_row[:R if hem is None else hem]
    if len(cloth) > 2:
        above = torch.cummax(cloth, 0).values
        under = torch.flip(torch.cummax(torch.flip(cloth, [0]), 0).values, [0])
        per_row[:len(cloth)] = torch.where(cloth < 0.5, torch.minimum(above, under), cloth)  # both >= cloth
    # ... and a row whose trained cloth the alpha loss was emptying (median below
    # ``_EMPTY_LAYER_OPACITY``: not yet at zero where few rays reached it) is empty: the hem band's
    # rows are dense, and eight rows of 0.04-0.09 under the coat photo's hem stacked to a grey haze
    per_row[per_row < _EMPTY_LAYER_OPACITY] = 0.0
    target = per_row[rows].clamp(_OPACITY_MARGIN, 1 - _OPACITY_MARGIN)
    param = model.layer_opacity
    new = torch.logit(target) / model.config.garment_opacity_gain
    param.data[todo.to(param.device)] = new[todo].to(param.device, param.dtype)
    return int(todo.sum())
