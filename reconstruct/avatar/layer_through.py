"""The garment layer's Gaussians under its hem that show the body behind them, not cloth: below a
skirt's hem the layer hangs in front of the legs, and training may make its Gaussians there opaque in
the legs' colour (the front fits either way: a transparent layer with the legs behind, or an opaque
one painted like them).

Why. The layer's unseen side takes its colour (``wrap_fill``) from the seen layer Gaussians at the
same height. On the grey-skirt photo the layer reaches below the hem in front of the legs; its seen
Gaussians there were skin-coloured and opaque, and the skirt's back took a band of skin colour
across its whole width in the rows above its hem.

Which. For each column of the layer's grid, the body's colour under the hem is the median colour of
the seen body Gaussians of the parts a layer covers within ``reach`` of the column's bottom
Gaussian and more than ``-edge_slack`` below it, among those the cloth does not hide
(``layer_cover``): the legs, or a coat's trousers, that the camera saw past the hem. All of them, at
least ``k``, not the few nearest: next to the hem those are the shadow between the legs, or took
the cloth's colour. The first 5 cm under the bottom row are left out for the same reason: on the
grey-skirt photo the right knee there drew the skirt's grey (its reference 0.55 0.55 0.52, within
``min_contrast`` of the cloth, so none of its 17 columns was read; from 5 cm down, skin: 137
flagged against 38 at 300 Stage I steps, reach 0.25 → 0.30 m). The cloth's colours are those of
the seen layer Gaussians more than ``depth`` in from both of the column's ends. Walking the column up from its bottom row (at most
``depth``), each seen opaque layer Gaussian whose colour is within ``tolerance`` of the body's, and
nearer to it than to the cloth's, shows the body; the walk stops at the first that does not (the
cloth). Unseen and transparent ones are passed over.

An open front (``_body_from_the_hem``). Under an open coat the legs show between its front edges
from the hem up; those layer Gaussians took the trousers' colour too, and among the cloth's colours
they made the cloth "of the body's colour" (the next paragraph but one), so no column was read. The
seen layer Gaussians joined to the bottom row by a chain of body-coloured ones are left out of the
cloth's colours. On the green-coat photo the coat's back had a dark band at its hem, 8 rows of
trousers colour carried round; 234 layer Gaussians are now flagged, and the back is the coat's green
down to the hem. A body-coloured print is not joined to the hem and stays the cloth's.

The layer's top is not read: there the body above it is mostly the same garment (a dress's bodice
on the torso over its skirt's layer), and on the synthetic dress of seed 2 the top rows flagged
that way left the back's top rows to the neckline's skin (unseen views -0.03 dB).

Colours are compared in an opponent space with brightness weighted down (``colour_distance``: the
lit knee and the shaded shin are one skin), each seen layer Gaussian's as the median of its row's
seen ones within ``window`` columns (a single Gaussian of a pleated skirt is near black or near
white), and the distance to the cloth is that to the nearest ``cloth_share`` of its colours (at
least ``k``): a hand or a few odd Gaussians inside it are not the cloth's colour. Where the cloth
has the body's colour somewhere inside (a skin-toned skirt, a print) the two cannot be told apart
and that column is left alone; when more than ``max_share`` of the seen layer would be flagged,
none is.

Arms and hands (``layer_shows_limbs``). Where an arm hangs beside the cloth or a hand rests on it, the
photo draws the arm over the layer's Gaussians; a fitted arm a few centimetres off the photo's
leaves the layer to draw it, opaque in the sleeve's or the hand's colour. On the long-skirt photo
(a skirt stretched sideways past the arms) such Gaussians, carried round at their heights, laid
light bands across the skirt's back. In each training frame (up to 8) the seen arm and hand
Gaussians are projected; a seen opaque layer Gaussian with at least ``k`` of them within ``reach``
in the image plane (at its own depth: the fitted arm is rarely at the layer's depth), whose colour
(the row's local median) is within ``tolerance`` of their median colour and nearer to it than to the
cloth's (the seen layer away from every arm), shows the arm. Nothing is marked where the cloth has
the arm's colour (``min_contrast``), or when more than ``max_share`` of the seen layer would be.

Behind an arm (``layer_behind_limbs``). A loose sleeve wider than the fitted arm, or a photo's hand a
little off the fitted one, leaves the layer behind the arm to draw it: its Gaussians there took the
sleeve's or the hand's colour, and a side view showed them on the garment's side as light patches
(the long-skirt photo from 225-300 degrees). In each training frame (up to 8) a seen layer Gaussian
whose nearest seen arm or hand Gaussian in the image lies within ``reach`` (metres at the layer
Gaussian's depth) and more than ``depth_gap`` nearer the camera, and whose own colour is nearer to
the arm's there (the median of the arm Gaussians within reach) than to the cloth's (its row's seen
layer away from every arm in that frame), drew the arm. Nothing is flagged where the arm's colour
is within ``min_contrast`` of the cloth's, or when more than ``max_share`` of the seen layer would
be. Those in front of the arm are left alone: they drew the arm over the fitted one, and made
transparent they let the fitted arm's filled colours into the photo's own view (the long skirt and
the open jacket: -0.6 dB inside the mask).

Use. Stage I's finish (``train/plan.py``, ``Stage1Config.layer_through``) takes them out of the
colour sources of the layer's unseen side; with ``Stage1Config.layer_behind_limbs`` those behind an
arm are unseen, and the fill gives them the cloth's colour (those next to the seen cloth keep their
decoded colour, as every unseen Gaussian of the fill's ring does). Their opacity, and the opacity fill, are left as they
are (counted as empty air in the fill, the open jacket photo's back came out shorter, over the
white shirt's hem).

Measured (docs/loose_clothing.md, "The legs under a hem"): on the grey-skirt photo (300 Stage I
steps) 167 of the layer's seen opaque Gaussians, in its bottom rows; the back's rows above the hem
went from skin (0.64, 0.53, 0.49) to the skirt's grey (0.41, 0.41, 0.40).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..body.parts import PART_INDEX
from .layer_clearance import covered_ids
from .layer_cover import model_body_under_layer


@dataclass(frozen=True)
class ThroughConfig:
    tolerance: float = 0.12  # a layer colour this close to the body's (``colour_distance``), and closer to it than to the cloth's, shows the body
    min_contrast: float = 0.08  # how far the body's colour must be from the cloth's for the two to be told apart
    luminance_weight: float = 0.5  # brightness against hue in ``colour_distance`` (shading moves brightness)
    depth: float = 0.12  # metres: how far up from the bottom row (in height) the walk goes
    reach: float = 0.30  # metres: the body Gaussians under the hem this close to the column's bottom Gaussian are its reference
    k: int = 8  # fewest reference Gaussians, and fewest cloth colours
    edge_slack: float = -0.05  # metres: "under the hem" starts this far above the bottom row (negative: below it)
    max_share: float = 0.5  # more than this share of the seen layer flagged: the garment is the body's colour
    cloth_share: float = 0.05  # a colour is the cloth's when this share of its colours (at least k) lie near it
    min_opacity: float = 0.5  # seen layer Gaussians less opaque than this are passed over
    window: int = 2  # columns: a seen layer Gaussian's colour is the median of the seen ones this close in its row


def layer_shows_body(body_positions: np.ndarray, body_parts: np.ndarray, body_colors: np.ndarray,
                     body_seen: np.ndarray, body_hidden: np.ndarray, layer_positions: np.ndarray,
                     layer_colors: np.ndarray, layer_seen: np.ndarray, layer_rc: np.ndarray,
                     grid_shape: tuple[int, int], layer_opacity: np.ndarray | None = None,
                     config: ThroughConfig = ThroughConfig()) -> np.ndarray:
    """(M,) bool over the layer's Gaussians: the seen ones that show the body behind them (module
    docstring). Canonical positions; ``body_hidden``: (N,) bool, the body Gaussians the cloth hides
    (``layer_cover.body_under_layer`` >= 0); ``layer_rc``: (M,2) grid row (0 the top) and column of
    each layer Gaussian on a ``grid_shape`` (rows, cols) grid; colours in [0, 1]."""
    cfg = config
    M = len(layer_positions)
    out = np.zeros(M, bool)
    layer_seen = np.asarray(layer_seen, bool)
    if layer_opacity is not None:  # a transparent Gaussian shows nothing: passed over like an unseen one
        layer_seen = layer_seen & (np.asarray(layer_opacity, np.float64) >= cfg.min_opacity)
    if M == 0 or not layer_seen.any():
        return out
    R, C = grid_shape
    rc = np.asarray(layer_rc, np.int64)
    index = np.full((R, C), -1, np.int64)
    index[rc[:, 0], rc[:, 1]] = np.arange(M)
    lpos = np.asarray(layer_positions, np.float64)
    lcol = np.asarray(layer_colors, np.float64)
    ids = covered_ids(body_parts)
    ref = ids[np.asarray(body_seen, bool)[ids] & ~np.asarray(body_hidden, bool)[ids]]
    if len(ref) < cfg.k:
        return out
    rpos = np.asarray(body_positions, np.float64)[ref]
    rcol = np.asarray(body_colors, np.float64)[ref]
    tree = cKDTree(rpos)
    w = cfg.luminance_weight
    local = _local_median(lcol, layer_seen, index, cfg.window)
    bodies = {}  # column -> the body's colour under its bottom Gaussian
    for c in range(C):
        e = index[R - 1, c]
        if e < 0:
            continue
        near = [j for j in tree.query_ball_point(lpos[e], cfg.reach) if rpos[j, 2] <= lpos[e, 2] + cfg.edge_slack]
        if len(near) >= cfg.k:
            bodies[c] = np.median(rcol[near], axis=0)
    # the cloth: the seen layer's colours farther than ``depth`` from both ends of their column, less
    # the body's colour reaching up from the bottom row (an open front)
    z = np.full((R, C), np.nan)
    z[rc[:, 0], rc[:, 1]] = lpos[:, 2]
    top, bottom = z[0, rc[:, 1]], z[R - 1, rc[:, 1]]
    opening = _body_from_the_hem(local, layer_seen, index, bodies, cfg)
    if opening.sum() > cfg.max_share * layer_seen.sum():
        return out  # the garment is the body's colour
    inside = layer_seen & ~opening & (top - lpos[:, 2] > cfg.depth) & (lpos[:, 2] - bottom > cfg.depth)
    if inside.sum() < cfg.k:
        return out
    cloth = cKDTree(opponent(local[inside], w))
    k_cloth = min(int(inside.sum()), max(cfg.k, int(np.ceil(cfg.cloth_share * inside.sum()))))

    def to_cloth(colour):  # distance to the cloth's k_cloth-th nearest colour (its odd few ignored)
        return cloth.query(opponent(colour, w), k=k_cloth)[0][-1]

    for c, body in bodies.items():
        e = index[R - 1, c]
        if to_cloth(body) < cfg.min_contrast:
            continue  # the cloth has the body's colour: the two cannot be told apart here
        for r in range(R - 1, -1, -1):
            i = index[r, c]
            if i < 0 or not layer_seen[i]:
                continue
            if lpos[i, 2] - lpos[e, 2] > cfg.depth:
                break
            to_body = colour_distance(local[i], body, w)
            if to_body > cfg.tolerance or to_body >= to_cloth(local[i]):
                break
            out[i] = True
    if out.sum() > cfg.max_share * layer_seen.sum():
        return np.zeros(M, bool)
    return out


def _body_from_the_hem(local: np.ndarray, seen: np.ndarray, index: np.ndarray, bodies: dict,
                       cfg: ThroughConfig) -> np.ndarray:
    """(M,) bool: the seen layer Gaussians joined to the bottom row (8-connected on the grid,
    wrapping round the tube) by seen ones whose colour (``local``) is within ``tolerance`` of the
    body's under the hem (``bodies``: column -> colour; each Gaussian is compared with the colour of
    the column its chain started from). Under an open coat the legs show between its front edges
    from the hem up: left among the cloth's colours, they made the cloth "of the body's colour" and
    no column under the hem was read. A body-coloured print within the cloth is not joined to the
    hem and stays the cloth's."""
    R, C = index.shape
    out = np.zeros(len(local), bool)
    w = cfg.luminance_weight
    stack = []
    for c, body in bodies.items():
        i = index[R - 1, c]
        if seen[i] and colour_distance(local[i], body, w) <= cfg.tolerance:
            out[i] = True
            stack.append((R - 1, c, body))
    while stack:
        r, c, body = stack.pop()
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                rr = r + dr
                if not 0 <= rr < R:
                    continue
                i = index[rr, (c + dc) % C]
                if i < 0 or out[i] or not seen[i] or colour_distance(local[i], body, w) > cfg.tolerance:
                    continue
                out[i] = True
                stack.append((rr, (c + dc) % C, body))
    return out


@dataclass(frozen=True)
class LimbConfig:
    reach: float = 0.05  # metres in the image plane (at the layer Gaussian's depth) to the nearest seen arm or hand Gaussian
    tolerance: float = 0.12  # as ``ThroughConfig.tolerance``, to the arm's colour there
    min_contrast: float = 0.08  # as ``ThroughConfig.min_contrast``
    luminance_weight: float = 0.5
    k: int = 8  # fewest arm Gaussians within reach, and fewest cloth colours
    max_share: float = 0.2  # more than this share of the seen layer flagged: none is
    cloth_share: float = 0.05
    min_opacity: float = 0.5
    window: int = 2


ARM_PARTS = ("upperarm.L", "lowerarm.L", "hand.L", "upperarm.R", "lowerarm.R", "hand.R")


def arm_mask(parts) -> np.ndarray:
    """(N,) bool: which of the part indices ``parts`` are an arm's or a hand's (``ARM_PARTS``)."""
    return np.isin(np.asarray(parts), [PART_INDEX[p] for p in ARM_PARTS])


def layer_shows_limbs(views, body_parts: np.ndarray, body_colors: np.ndarray, body_seen: np.ndarray,
                      layer_colors: np.ndarray, layer_seen: np.ndarray, layer_rc: np.ndarray,
                      grid_shape: tuple[int, int], layer_opacity: np.ndarray | None = None,
                      config: LimbConfig = LimbConfig()) -> np.ndarray:
    """(M,) bool over the layer's Gaussians: the seen ones that show an arm or a hand, not cloth
    (module docstring, "Arms and hands"). ``views``: (camera, body_means (N,3), layer_means (M,3))
    of the training frames, posed; the rest as ``layer_shows_body``."""
    cfg = config
    M = len(layer_colors)
    out = np.zeros(M, bool)
    layer_seen = np.asarray(layer_seen, bool)
    if layer_opacity is not None:
        layer_seen = layer_seen & (np.asarray(layer_opacity, np.float64) >= cfg.min_opacity)
    arms = np.flatnonzero(arm_mask(body_parts) & np.asarray(body_seen, bool))
    if M == 0 or layer_seen.sum() < cfg.k or len(arms) < cfg.k:
        return out
    R, C = grid_shape
    rc = np.asarray(layer_rc, np.int64)
    index = np.full((R, C), -1, np.int64)
    index[rc[:, 0], rc[:, 1]] = np.arange(M)
    w = cfg.luminance_weight
    local = _local_median(np.asarray(layer_colors, np.float64), layer_seen, index, cfg.window)
    bcol = np.asarray(body_colors, np.float64)[arms]
    cand = np.flatnonzero(layer_seen)
    # the arm's colour round each seen layer Gaussian, in some view
    arm = median_colour_within(views, (1, arms), bcol, (2, cand), cfg.reach, cfg.k)
    by_arm = np.isfinite(arm[:, 0])
    if not by_arm.any() or (~by_arm).sum() < cfg.k:
        return out
    cloth = cKDTree(opponent(local[cand[~by_arm]], w))  # the cloth: seen layer away from the arms
    k_cloth = min(int((~by_arm).sum()), max(cfg.k, int(np.ceil(cfg.cloth_share * (~by_arm).sum()))))
    to_cloth = lambda colour: cloth.query(opponent(colour, w), k=k_cloth)[0][..., -1]  # noqa: E731
    j = np.flatnonzero(by_arm)
    to_arm = colour_distance(local[cand[j]], arm[j], w)
    out[cand[j]] = (to_cloth(arm[j]) >= cfg.min_contrast) & (to_arm <= cfg.tolerance) & (to_arm < to_cloth(local[cand[j]]))
    if out.sum() > cfg.max_share * layer_seen.sum():
        return np.zeros(M, bool)
    return out


@dataclass(frozen=True)
class BehindConfig:
    reach: float = 0.03  # metres in the image plane (at the layer Gaussian's depth) to the nearest seen arm or hand Gaussian
    depth_gap: float = 0.03  # metres further from the camera than that arm Gaussian
    min_contrast: float = 0.08  # the arm's colour there this far from the cloth's at least, or no telling them apart
    luminance_weight: float = 0.5
    k: int = 8  # fewest seen arm Gaussians in a frame, and fewest cloth Gaussians in a row for its own colour
    max_share: float = 0.2  # more than this share of the seen layer flagged: none is


def layer_behind_limbs(views, body_parts: np.ndarray, body_colors: np.ndarray, body_seen: np.ndarray,
                       layer_colors: np.ndarray, layer_seen: np.ndarray, layer_rc: np.ndarray,
                       config: BehindConfig = BehindConfig()) -> np.ndarray:
    """(M,) bool over the layer's Gaussians: the seen ones that lie behind an arm or a hand in some
    training frame and drew it there (module docstring, "Behind an arm"). ``views``: (camera,
    body_means (N,3), layer_means (M,3)) of the training frames, posed; ``layer_rc``: each layer
    Gaussian's (row, column) in its grid (a row's seen cloth gives it the cloth's colour)."""
    cfg = config
    M = len(layer_colors)
    out = np.zeros(M, bool)
    layer_seen = np.asarray(layer_seen, bool)
    arms = np.flatnonzero(arm_mask(body_parts) & np.asarray(body_seen, bool))
    if M == 0 or layer_seen.sum() < cfg.k or len(arms) < cfg.k:
        return out
    w = cfg.luminance_weight
    lcol = np.asarray(layer_colors, np.float64)
    bcol = np.asarray(body_colors, np.float64)[arms]
    rows = np.asarray(layer_rc, np.int64)[:, 0]
    cand = np.flatnonzero(layer_seen)
    for camera, body_means, layer_means in views:
        buv, bz = camera.project(np.asarray(body_means, np.float64)[arms])
        front = bz > 0
        if front.sum() < cfg.k:
            continue
        buv, bz, fcol = buv[front], bz[front], bcol[front]
        tree = cKDTree(buv)
        luv, lz = camera.project(np.asarray(layer_means, np.float64)[cand])
        ok = lz > 0
        dist, j = tree.query(luv)
        radius = cfg.reach * camera.fx / np.where(ok, lz, 1.0)  # pixels
        near = ok & (dist <= radius)
        behind = near & (lz - bz[j] > cfg.depth_gap)
        if not behind.any() or (~near).sum() < cfg.k:
            continue
        # the cloth's colour: the median of its row's seen layer Gaussians away from every arm in
        # this frame (the whole seen cloth's where the row has too few)
        cloth_all = np.median(lcol[cand[~near]], axis=0)
        idx = np.flatnonzero(behind)
        cloth = np.empty((len(idx), 3))
        for r in np.unique(rows[cand[idx]]):
            in_row = ~near & (rows[cand] == r)
            colour = np.median(lcol[cand[in_row]], axis=0) if in_row.sum() >= cfg.k else cloth_all
            cloth[rows[cand[idx]] == r] = colour
        arm = np.array([np.median(fcol[nb], axis=0)
                        for nb in tree.query_ball_point(luv[idx], radius[idx])])  # non-empty: the nearest is in
        own = lcol[cand[idx]]
        like = (colour_distance(arm, cloth, w) >= cfg.min_contrast) & (colour_distance(own, arm, w) < colour_distance(own, cloth, w))
        out[cand[idx[like]]] = True
    if out.sum() > cfg.max_share * layer_seen.sum():
        return np.zeros(M, bool)
    return out


def median_colour_within(views, src: tuple[int, np.ndarray], src_colors: np.ndarray, dst: tuple[int, np.ndarray],
                         reach: float, k: int) -> np.ndarray:
    """(len(dst ids), 3): for each destination Gaussian, the median colour of the source Gaussians
    within ``reach`` metres of it in the image plane (at the destination's depth) in the first of
    ``views`` where at least ``k`` lie there; NaN where none does. ``views``: (camera, body_means,
    layer_means); ``src`` / ``dst``: (which means of a view, 1 the body's or 2 the layer's; ids into
    them); ``src_colors``: the sources' colours. A view with fewer than ``k`` sources in front of
    its camera is passed over."""
    (si, sids), (di, dids) = src, dst
    out = np.full((len(dids), 3), np.nan)
    for view in views:
        camera = view[0]
        suv, sz = camera.project(np.asarray(view[si], np.float64)[sids])
        front = sz > 0
        if front.sum() < k:
            continue
        tree = cKDTree(suv[front])
        colours = src_colors[front]
        duv, dz = camera.project(np.asarray(view[di], np.float64)[dids])
        todo = np.flatnonzero((dz > 0) & np.isnan(out[:, 0]))
        radius = reach * camera.fx / dz[todo]  # pixels
        for j, near in zip(todo, tree.query_ball_point(duv[todo], radius)):
            if len(near) >= k:
                out[j] = np.median(colours[near], axis=0)
    return out


def opponent(colors: np.ndarray, luminance_weight: float = 0.5) -> np.ndarray:
    """RGB colours (..., 3) in an opponent space: (r - g, g - b, ``luminance_weight`` times the mean
    brightness)."""
    x = np.asarray(colors, np.float64)
    return np.stack([x[..., 0] - x[..., 1], x[..., 1] - x[..., 2], luminance_weight * x.mean(-1)], -1)


def colour_distance(a: np.ndarray, b: np.ndarray, luminance_weight: float = 0.5) -> np.ndarray:
    """Distance between RGB colours in the ``opponent`` space. Light and shadow on one surface move
    its brightness more than its hue: on the grey-skirt photo the lit knees (0.70, 0.57, 0.51) are
    0.18 from the shaded shins (0.64, 0.45, 0.39) in RGB and 0.16 from the skirt's grey, here 0.08
    and 0.14."""
    return np.linalg.norm(opponent(a, luminance_weight) - opponent(b, luminance_weight), axis=-1)


def _local_median(colors: np.ndarray, seen: np.ndarray, index: np.ndarray, h: int) -> np.ndarray:
    """(M,3): for each seen layer Gaussian the per-channel median colour of the seen ones in its row
    within ``h`` columns (wrapping round the tube). A single Gaussian's colour is too noisy to
    classify (on the pleated grey skirt neighbours alternate between 0.06 and 0.84); the window runs
    along the row, across pleats, and not across a hem, which runs along the rows."""
    R, C = index.shape
    out = colors.copy()
    for r, c in zip(*np.nonzero(index >= 0)):
        i = index[r, c]
        if not seen[i]:
            continue
        win = index[r, np.arange(c - h, c + h + 1) % C]
        win = win[win >= 0]
        win = win[seen[win]]
        out[i] = np.median(colors[win], axis=0)
    return out


def model_layer_shows_body(model, seen, colors, config: ThroughConfig = ThroughConfig()) -> np.ndarray | None:
    """``layer_shows_body`` for an ``AvatarModel``: (N+M,) bool over all its Gaussians (False on the
    body's), from the (N+M,) ``seen`` flags and canonical ``colors`` (CPU arrays or tensors); None
    without a layer. The cloth hides the body where ``layer_cover.model_body_under_layer`` says so
    (the layer's current opacities)."""
    if model.layer is None or model.num_layer == 0:
        return None
    N = model.num_body
    pos = model.base_positions.detach().cpu().double().numpy()
    col = np.asarray(colors, np.float64)
    seen = np.asarray(seen, bool)
    hidden = model_body_under_layer(model)[:N] >= 0
    opacity = model.opacities().detach().cpu().double().numpy()[N:]
    return _on_layer(layer_shows_body(pos[:N], model.parts()[:N], col[:N], seen[:N], hidden, pos[N:], col[N:],
                                      seen[N:], model.layer_rc.cpu().numpy(), model.layer.grid_shape, opacity, config), N)


def model_layer_shows_limbs(model, seen, colors, views, config: LimbConfig = LimbConfig()) -> np.ndarray | None:
    """``layer_shows_limbs`` for an ``AvatarModel``: (N+M,) bool (False on the body's) from the
    (N+M,) ``seen`` flags and canonical ``colors``; ``views``: (camera, posed means (N+M,3)) of the
    training frames. None without a layer."""
    if model.layer is None or model.num_layer == 0:
        return None
    N, col, seen, split, opacity = _split_views(model, seen, colors, views)
    return _on_layer(layer_shows_limbs(split, model.parts()[:N], col[:N], seen[:N], col[N:], seen[N:],
                                       model.layer_rc.cpu().numpy(), model.layer.grid_shape, opacity, config), N)


def model_layer_behind_limbs(model, seen, colors, views, config: BehindConfig = BehindConfig()) -> np.ndarray | None:
    """``layer_behind_limbs`` for an ``AvatarModel``, with the inputs and output of
    ``model_layer_shows_limbs``."""
    if model.layer is None or model.num_layer == 0:
        return None
    N, col, seen, split, _ = _split_views(model, seen, colors, views)
    return _on_layer(layer_behind_limbs(split, model.parts()[:N], col[:N], seen[:N], col[N:], seen[N:],
                                        model.layer_rc.cpu().numpy(), config), N)


def _split_views(model, seen, colors, views):
    """The model-level calls' inputs: the body's count N, the colours and seen flags as arrays, each
    view's posed means split into the body's and the layer's, and the layer's opacities."""
    N = model.num_body
    split = [(cam, np.asarray(means)[:N], np.asarray(means)[N:]) for cam, means in views]
    opacity = model.opacities().detach().cpu().double().numpy()[N:]
    return N, np.asarray(colors, np.float64), np.asarray(seen, bool), split, opacity


def _on_layer(flags: np.ndarray, num_body: int) -> np.ndarray:
    """(N+M,) bool: the layer's (M,) ``flags`` after N False for the body's Gaussians."""
    return np.concatenate([np.zeros(num_body, bool), np.asarray(flags, bool)])
