"""The back of a head, neck and shoulders under hair a photo shows only from the front: how far the
hair falls and what colour it is, read in the images (the wrap fill's ``hair_back_parts``).

Why. The wrap fill carries colours round in canonical space, and from the front the hair a person
wears down is seen only round the face and over the shoulders. In canonical space those strands
are not joined to the head (the neck between them shows no hair), and the head's hair rule
(``hair.py``) reads only the head's rim: the back of a long-haired head ended at the skull and the
neck and upper back below it took the dress's colour -- short hair from behind. The rule's colour
cluster also misses lit strands (on blonde hair they cluster with the face), so the back of the
head came out the brown of the shadowed strands (the red-dress photo).

**The hair in a frame** (``hair_rows``). Seeds: where the head's seen hair Gaussians project
(``hair.hair_and_face``). A person's pixel is hair-coloured when its colour lies within
``tolerance`` in every channel of a seed's, at least ``HAIR_SHARE`` of the seeds lie within half
of it, and ``RIVAL_RATIO`` times more than of any rival group: the face's skin (the face's middle
in its colour cluster), and the clothes and skin where hair does not fall (the torso's lower half,
a garment layer beside it, the forearms and hands). A share, not the nearest colour: a few black
buttons or the shadow between folded arms among the rivals do not take black hair from it, and a
top in the hair's own colour does. Hair-coloured pixels are joined across one-pixel gaps; the
pieces that hold ``SEED_SHARE`` of the seeds are the hair, with the pieces within ``JOIN_REACH``
of the face's height of them (hair below a hat, past an ear) and those touching the face's hull
(``FACE_TOUCH``: strands a tilted face cuts off from the hair above), their holes filled (lit
strands inside), less the face's middle (``face_middle``: by the body's geometry, not colour).

**What it covers behind** (``HairRows``). Hair worn down covers, on each image row it reaches, the
span its strands mark there -- symmetric about the face's middle column and as wide as the farther
strand, smoothed over the rows: hair falling further over one shoulder than the other in front
still hangs from the whole back of the head. Each unseen Gaussian of the parts behind its part's
centre whose twin (the front's Gaussian at its left-right place and height) projects into that
span takes the hair's colour on that row: the mean of the middle
half by brightness of the hair's pixels (inside the silhouette by ``EDGE_PX``) within
``COLOUR_REACH`` of the hair's height, lit and shadowed strands mixed as a view from behind mixes
them. The neck and back are covered only in frames where the hair falls past the neck
(``falls_past_neck``): hair cut at the jaw leaves the back of the neck to its hairline. Over
several frames (a video that never turned) a Gaussian is covered where at least half of the frames
it projects into cover it, with the median of their colours; on the texel grid the cover's edge is
smoothed and strips thinner than ``OPEN_TEXELS`` go (``smooth_cover``); and a part is covered only
below a part that is (``hung_from_above``: the head, then the neck, then the back), and the back
in the pieces that reach down its middle (``down_the_middle``).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from .cut_fill import FrameView

MIN_SEEDS = 16  # seen hair Gaussians on the person's pixels needed to read the hair in a frame
SEED_SHARE = 0.05  # share of the seeds a connected piece of hair-coloured pixels must hold to count
ROW_REACH = 3  # rows either side over which the span's edges are smoothed
# share of the hair's height either side of a row whose hair pixels give the row's colour (at
# least ``ROW_REACH``)
COLOUR_REACH = 0.15
FACE_MARGIN = 1  # pixels the face's projected hull is grown by
EDGE_PX = 2  # pixels inside the silhouette's edge whose colours the hair's colour leaves out
SMOOTH_SWEEPS = 2  # majority sweeps over the cover's edge on the texel grid (``smooth_cover``)
OPEN_TEXELS = 3  # texels of the opening that takes strips of cover away (``smooth_cover``)
HANG_SHARE = 0.5  # share of a part's candidates covered for the part below to be (``hung_from_above``)
MIDDLE_COLUMN = 0.04  # metres either side of the head's middle that the back's cover must reach (``down_the_middle``)
JOIN_3D = 0.015  # metres within which covered Gaussians are one piece (``down_the_middle``)
# share of the hair's points a hair-coloured pixel needs within half the tolerance of its colour:
# the colours the hair shows often, not its rare ones (the coat photo's grey beanie edge, whose
# colours are the coat's shadows)
HAIR_SHARE = 0.03
# ... and this many times the share of any rival group's points there
RIVAL_RATIO = 3.0
# share of the face's middle's height in the image within which a piece of hair-coloured pixels
# joins the hair held by the seeds: a beanie held the coat photo's seeds, and her black hair below
# it, past her ears, was a piece of its own
JOIN_REACH = 0.5
# pixels from the face's hull (``face_hull``, which is no hair) within which a piece of
# hair-coloured pixels is hair framing the face, however far from the seeds' pieces: strands over
# a shoulder that the face, turned or tilted, cuts off from the hair above it (the coat photo's
# left strand, 16 px from her beret's piece in one run and 25 in another, the reach being 21)
FACE_TOUCH = 2
# the face's middle on the body's head, in shares of the head's height (canonical: facing -Y, +Z
# up): within FACE_HALF_WIDTH either side of the nose (the head's foremost point), from FACE_BELOW
# below it to FACE_ABOVE above it, in front of the head's centre -- eyes, nose, mouth and cheeks
# (anny's head, 0.235 m from under the jaw to the crown: 4.5 cm either side, 5 cm below, 5.4 above)
FACE_HALF_WIDTH = 0.19
FACE_BELOW = 0.21
FACE_ABOVE = 0.23


@dataclass
class HairRows:
    """The hair one frame shows, row by row: ``left``/``right`` (H,) the span it covers behind
    (NaN on rows without hair), ``colour`` (H,3) its colour there, and the ``region`` (H,W) bool
    of hair pixels it was read from."""

    left: np.ndarray
    right: np.ndarray
    colour: np.ndarray
    region: np.ndarray

    @property
    def end(self) -> float:
        """The row below the hair's lowest (its strands' tips in the image)."""
        return float(np.flatnonzero(np.isfinite(self.left))[-1] + 1)

    def covers(self, uv: np.ndarray) -> np.ndarray:
        """(S,) bool: the points ``uv`` (S,2) that lie within a row's span of hair."""
        h = len(self.left)
        row = np.floor(uv[:, 1]).astype(np.int64)
        ok = (row >= 0) & (row < h)
        r = np.clip(row, 0, h - 1)
        with np.errstate(invalid="ignore"):
            return ok & (uv[:, 0] >= self.left[r]) & (uv[:, 0] <= self.right[r])

    def colour_at(self, uv: np.ndarray) -> np.ndarray:
        r = np.clip(np.floor(uv[:, 1]).astype(np.int64), 0, len(self.left) - 1)
        return self.colour[r]


def _pixels(uv: np.ndarray, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    h, w = shape
    x = np.clip(np.floor(uv[:, 0]).astype(np.int64), 0, w - 1)
    y = np.clip(np.floor(uv[:, 1]).astype(np.int64), 0, h - 1)
    return x, y


def face_middle(head_pos: np.ndarray) -> np.ndarray:
    """(H,) bool over a head's canonical Gaussian positions ``head_pos`` (H,3): the face's middle
    (``FACE_HALF_WIDTH``, ``FACE_BELOW``, ``FACE_ABOVE``), by the body's geometry alone -- hair
    framing the face does not enter it, whatever its colour."""
    head_pos = np.asarray(head_pos, np.float64)
    if not len(head_pos):
        return np.zeros(0, bool)
    height = np.ptp(head_pos[:, 2])
    nose = head_pos[head_pos[:, 1].argmin()]
    dz = head_pos[:, 2] - nose[2]
    return ((np.abs(head_pos[:, 0] - nose[0]) <= FACE_HALF_WIDTH * height) & (dz >= -FACE_BELOW * height)
            & (dz <= FACE_ABOVE * height) & (head_pos[:, 1] < head_pos[:, 1].mean()))


def face_hull(face_uv: np.ndarray, shape: tuple[int, int], margin: int = FACE_MARGIN) -> np.ndarray:
    """(H,W) bool: the pixels inside the convex hull of the face's projected Gaussians ``face_uv``,
    grown by ``margin``; none when they span no area."""
    out = np.zeros(shape, bool)
    if len(face_uv) < 3:
        return out
    from scipy.spatial import Delaunay, QhullError

    try:
        tri = Delaunay(face_uv)
    except (QhullError, ValueError):
        return out
    h, w = shape
    x0, y0 = np.maximum(np.floor(face_uv.min(0)).astype(int), 0)
    x1, y1 = np.minimum(np.ceil(face_uv.max(0)).astype(int) + 1, [w, h])
    if x1 <= x0 or y1 <= y0:
        return out
    ys, xs = np.mgrid[y0:y1, x0:x1]
    inside = tri.find_simplex(np.stack([xs.ravel() + 0.5, ys.ravel() + 0.5], 1)) >= 0
    out[y0:y1, x0:x1] = inside.reshape(ys.shape)
    return ndimage.binary_dilation(out, iterations=margin) if margin else out


def _colours_under(image: np.ndarray, person: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(S,3) the colours of ``image`` under the points ``uv`` (S,2) that fall on the person."""
    x, y = _pixels(uv, person.shape)
    on = person[y, x]
    return image[y[on], x[on]]


def share_near(samples: np.ndarray, colours: np.ndarray, radius: float) -> np.ndarray:
    """(P,) about the share of ``samples`` (S,3) within ``radius`` in every channel of each of
    ``colours`` (P,3), colours in [0, 1]: counted on a grid of cells ``radius`` / 2 wide, over the
    5 x 5 x 5 cells round each colour's own; zeros when there are no samples."""
    if not len(samples):
        return np.zeros(len(colours))
    bins = max(1, int(np.ceil(2.0 / radius)))

    def cell(c: np.ndarray) -> tuple[np.ndarray, ...]:
        return tuple(np.clip((np.asarray(c) * bins).astype(np.int64), 0, bins - 1).T)

    hist = np.zeros((bins, bins, bins))
    np.add.at(hist, cell(samples), 1.0)
    box = ndimage.uniform_filter(hist, size=5, mode="constant") * 125.0
    return box[cell(colours)] / len(samples)


def middle_mean(colours: np.ndarray) -> np.ndarray:
    """(3,) the mean of the middle half of ``colours`` (S,3) by brightness: lit and shadowed strands
    mixed, without the brightest and darkest quarters (an ear's skin among dark hair, a shadow)."""
    order = np.argsort(colours.sum(1), kind="stable")
    lo, hi = len(order) // 4, len(order) - len(order) // 4
    return colours[order[lo:hi] if hi > lo else order].mean(0)


def hair_coloured(image: np.ndarray, person: np.ndarray, seeds: np.ndarray, allowed: np.ndarray,
                  rival_uvs: Sequence[np.ndarray], tolerance: float) -> np.ndarray:
    """(H,W) bool: the ``allowed`` pixels in the hair's colours (module docstring): within
    ``tolerance`` of a colour of the ``seeds`` (S,3), shared by ``HAIR_SHARE`` of them and by
    ``RIVAL_RATIO`` times more of them than of any rival group's points (``rival_uvs``)."""
    ys, xs = np.nonzero(allowed)
    colours = image[ys, xs]
    near = cKDTree(np.unique(seeds, axis=0)).query(colours, p=np.inf)[0] <= tolerance
    hair_share = share_near(seeds, colours[near], 0.5 * tolerance)
    rival_share = np.zeros(int(near.sum()))
    for uv in rival_uvs:
        rival_share = np.maximum(rival_share, share_near(_colours_under(image, person, uv), colours[near],
                                                         0.5 * tolerance))
    near[near] = (hair_share > RIVAL_RATIO * rival_share) & (hair_share >= HAIR_SHARE)
    like = np.zeros(allowed.shape, bool)
    like[ys[near], xs[near]] = True
    return like


def hair_region(like: np.ndarray, allowed: np.ndarray, seed_px: tuple[np.ndarray, np.ndarray],
                face_height: float, face: np.ndarray | None = None) -> np.ndarray | None:
    """(H,W) bool: the hair among the hair-coloured pixels ``like`` (module docstring): joined
    across one-pixel gaps, the pieces holding ``SEED_SHARE`` of the seeds (``seed_px``: their
    (x, y) pixels), those within ``JOIN_REACH`` of the ``face_height`` (pixels) of them and, with
    the face's hull ``face`` (H,W) bool, those within ``FACE_TOUCH`` pixels of it (hair framing the
    face), holes filled, within ``allowed``; None when no piece holds enough seeds."""
    joined = ndimage.binary_closing(like, structure=np.ones((3, 3), bool)) & allowed | like
    labels, n = ndimage.label(joined, structure=np.ones((3, 3), bool))
    if n == 0:
        return None
    x, y = seed_px
    held = np.bincount(labels[y, x], minlength=n + 1)
    held[0] = 0
    keep = held >= max(2, SEED_SHARE * len(x))
    if not keep.any():
        return None
    # pieces of hair within reach of those: hair below a hat, past an ear or a glasses' arm
    reach = int(round(JOIN_REACH * face_height))
    if reach > 0:
        near_kept = ndimage.binary_dilation(keep[labels], iterations=reach)
        keep[np.unique(labels[near_kept & (labels > 0)])] = True
    if face is not None and face.any():
        by_face = ndimage.binary_dilation(face, iterations=FACE_TOUCH, structure=np.ones((3, 3), bool))
        keep[np.unique(labels[by_face & (labels > 0)])] = True
    return ndimage.binary_fill_holes(keep[labels]) & allowed


def rows_of(region: np.ndarray, image: np.ndarray, person: np.ndarray, centre: float) -> HairRows:
    """The span the hair ``region`` covers behind on each row, symmetric about the ``centre``
    column, and its colour there (module docstring)."""
    h = region.shape[0]
    left = np.full(h, np.nan)
    right = np.full(h, np.nan)
    colour = np.full((h, 3), np.nan)
    rows = np.flatnonzero(region.any(1))
    reach = max(ROW_REACH, int(round(COLOUR_REACH * (rows[-1] - rows[0] + 1))))
    # the colour from inside the person (the silhouette's edge pixels are blended with the
    # background), on the rows where there is any
    inner = region & ndimage.binary_erosion(person, iterations=EDGE_PX)
    for r in rows:
        band = slice(max(r - reach, 0), r + reach + 1)
        pixels = image[band][inner[band]]
        colour[r] = middle_mean(pixels if len(pixels) else image[band][region[band]])
    # as wide on each row as the hair reaches out on either side there (strands over one shoulder
    # longer than over the other still hang from the whole back of the head), the half-width
    # smoothed over the colour's rows (a strand's ragged tip is not the hair's edge behind)
    half = np.zeros(h)
    for r in rows:
        cols = np.flatnonzero(region[r])
        half[r] = max(centre - cols[0], cols[-1] + 1.0 - centre, 0.0)
    half[rows] = ndimage.median_filter(half[rows[0]: rows[-1] + 1], size=2 * reach + 1, mode="nearest")[rows - rows[0]]
    left[rows] = centre - half[rows]
    right[rows] = centre + half[rows]
    return HairRows(left, right, colour, region)


def hair_rows(image: np.ndarray, mask: np.ndarray, hair_uv: np.ndarray, face_uv: np.ndarray,
              rival_uvs: Sequence[np.ndarray], *, tolerance: float) -> HairRows | None:
    """The hair of one frame (module docstring): ``image`` (H,W,3) in [0,1], person ``mask`` (H,W),
    the projections of the head's seen hair Gaussians ``hair_uv`` (S,2), of its face's middle
    ``face_uv`` (F,2) and of groups of seen Gaussians whose colours are not the hair's,
    ``rival_uvs`` (the face's skin; the clothes and skin where hair does not fall), in pixels.
    None when fewer than ``MIN_SEEDS`` of the hair's points fall on the person or no piece of
    hair-coloured pixels holds enough of them."""
    image = np.asarray(image, np.float64)
    person = np.asarray(mask) > 0.5
    x, y = _pixels(hair_uv, person.shape)
    on = person[y, x]
    x, y = x[on], y[on]
    if len(x) < MIN_SEEDS:
        return None
    hull = face_hull(face_uv, person.shape)
    allowed = person & ~hull
    like = hair_coloured(image, person, image[y, x], allowed, rival_uvs, tolerance)
    region = hair_region(like, allowed, (x, y), float(np.ptp(face_uv[:, 1])) if len(face_uv) else 0.0, hull)
    if region is None:
        return None
    return rows_of(region, image, person, float(np.median((face_uv if len(face_uv) else hair_uv)[:, 0])))


def falls_past_neck(rows: HairRows, neck_uv: np.ndarray) -> bool:
    """Whether the hair of ``rows`` ends below the neck's lowest point in the image (``neck_uv``,
    the projection of the neck's Gaussians): worn down onto the shoulders. Hair cut short ends at
    the jaw, above it (the synthetic scenes' short cut 2 px above it; long hair over the shoulders
    2-37 px below it on five photos)."""
    return bool(len(neck_uv)) and rows.end > neck_uv[:, 1].max()


def hair_back_colors(n: int, candidates: np.ndarray, hair: np.ndarray, face: np.ndarray,
                     rivals: Sequence[np.ndarray], views: Iterable[FrameView], *, tolerance: float,
                     hanging: np.ndarray | None = None, neck: np.ndarray | None = None,
                     twins: np.ndarray | None = None) -> np.ndarray:
    """(n,3) float32, NaN but for the ``candidates`` (indices: unseen Gaussians behind their part's
    centre) the hair covers in the images (module docstring), which take its colour there. Each
    candidate is read where its ``twin`` projects (``twins``: (C,) indices; None: itself): the
    Gaussian in front of it at its left-right place and height, which the image shows under the
    strands that frame the hair behind -- the back itself projects beside the front wherever the
    body is turned from the camera.
    ``hair``: indices of the head's seen hair Gaussians; ``face``: of its face's middle
    (``face_middle``); ``rivals``: groups of indices of seen Gaussians whose colours are not the hair's
    (``hair_rows``); ``views``: the frames, read once. ``hanging``: (C,) bool over the candidates,
    those below the head (the neck, the back), which the hair covers only in frames where it falls
    past the neck (``falls_past_neck`` on the ``neck``'s Gaussians): hair cut short ends at the jaw
    in front, and the back of the neck, which a frontal view shows at the jaw's height, is skin
    below its hairline."""
    out = np.full((n, 3), np.nan, np.float32)
    candidates = np.asarray(candidates, np.int64)
    if not len(candidates) or len(hair) < MIN_SEEDS:
        return out
    covered_votes = np.zeros(len(candidates))
    frames_in = np.zeros(len(candidates))
    colours: list[np.ndarray] = []
    for view in views:
        inside = view.inside()
        rows = hair_rows(view.image, view.mask, view.uv[hair[inside[hair]]], view.uv[face[inside[face]]],
                         [view.uv[r[inside[r]]] for r in rivals], tolerance=tolerance)
        read = candidates if twins is None else np.asarray(twins, np.int64)
        here = inside[read]
        frames_in += here
        got = np.full((len(candidates), 3), np.nan)
        if rows is not None:
            cov = here & rows.covers(view.uv[read])
            if hanging is not None and (neck is None or not falls_past_neck(rows, view.uv[neck[inside[neck]]])):
                cov &= ~np.asarray(hanging, bool)
            covered_votes += cov
            got[cov] = rows.colour_at(view.uv[read[cov]])
        colours.append(got)
    if not colours:
        return out
    take = (covered_votes > 0) & (covered_votes >= 0.5 * frames_in)
    if take.any():
        out[candidates[take]] = np.nanmedian(np.stack(colours)[:, take], axis=0)
    return out


def smooth_cover(colors: np.ndarray, candidates: np.ndarray, neighbours: np.ndarray, sweeps: int = SMOOTH_SWEEPS,
                 opening: int = OPEN_TEXELS) -> np.ndarray:
    """``colors`` (n,3) of ``hair_back_colors`` with its cover smoothed on the texel grid
    (``neighbours`` (n,K), -1 for none; only the ``candidates`` change). First a majority over
    ``sweeps`` sweeps: a candidate is covered when more than half of itself and its neighbours
    among the candidates are, one newly covered taking the mean colour of its covered neighbours
    (single texels in or out along the edge read as a dotted line from behind). Then an opening
    by ``opening`` texels: a strip of cover thinner than that goes (hair that ends at the nape
    covered the top of the torso's back, round the neck's base, as a line across the shoulders)."""
    out = np.array(colors, np.float64, copy=True)
    candidates = np.asarray(candidates, np.int64)
    if not len(candidates):
        return out.astype(np.float32)
    nb = np.asarray(neighbours)[candidates]
    is_candidate = np.zeros(len(out), bool)
    is_candidate[candidates] = True
    ok = (nb >= 0) & is_candidate[np.maximum(nb, 0)]
    at = np.maximum(nb, 0)
    for _ in range(sweeps):
        covered = np.isfinite(out).all(1)
        c_nb = covered[at] & ok
        keep = 2 * (c_nb.sum(1) + covered[candidates]) > ok.sum(1) + 1
        mean = np.where(c_nb[..., None], np.nan_to_num(out[at]), 0.0).sum(1) / np.maximum(c_nb.sum(1), 1)[:, None]
        new = out[candidates]
        new[~keep] = np.nan
        grow = keep & ~covered[candidates]
        new[grow] = mean[grow]
        out[candidates] = new
    covered = np.isfinite(out).all(1)
    core = covered.copy()
    for _ in range(opening):  # erode: every neighbour among the candidates covered
        core[candidates] &= (core[at] | ~ok).all(1)
    for _ in range(opening):  # dilate back, within the cover
        core[candidates] |= covered[candidates] & (core[at] & ok).any(1)
    out[candidates[~core[candidates]]] = np.nan
    return out.astype(np.float32)


def hung_from_above(colors: np.ndarray, groups: Sequence[np.ndarray], shares: Sequence[float] | None = None) -> np.ndarray:
    """``colors`` (n,3) of ``hair_back_colors`` with the cover of each group of candidates (the
    parts from the head down, in order: ``groups``, index arrays) taken away unless the group above
    it is covered on more than ``shares[i]`` of its candidates (``HANG_SHARE`` each by default): hair
    hangs from the head down the neck to the back. Where hair tied back covered the tops of the
    shoulders beside a neck it left bare (the group photo's second woman), the shoulders kept two
    patches of it."""
    out = np.array(colors, np.float32, copy=True)
    shares = [HANG_SHARE] * len(groups) if shares is None else list(shares)
    held = True
    for group, share in zip(groups, shares):
        group = np.asarray(group, np.int64)
        if not held:
            out[group] = np.nan
        covered = np.isfinite(out[group]).all(1).mean() if len(group) else 0.0
        held = held and covered > share
    return out


def down_the_middle(colors: np.ndarray, group: np.ndarray, pos: np.ndarray, middle_x: float,
                    column: float = MIDDLE_COLUMN, reach: float = JOIN_3D) -> np.ndarray:
    """``colors`` (n,3) with the cover of the candidates ``group`` kept only in its pieces (joined
    within ``reach`` metres, canonical positions ``pos``) that reach the column within ``column``
    of ``middle_x`` (the head's middle): hair hangs down the middle of the back. Where hair tied
    back ended by the neck, the mirrored tips of its strands covered the tops of both shoulders
    and not the back between them (the group photo's second woman)."""
    out = np.array(colors, np.float32, copy=True)
    group = np.asarray(group, np.int64)
    got = group[np.isfinite(out[group]).all(1)]
    if not len(got):
        return out
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    pairs = cKDTree(pos[got]).query_pairs(reach, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(got), len(got)))
    _, label = connected_components(graph, directed=False)
    middle = np.abs(pos[got, 0] - middle_x) <= column
    keep = np.isin(label, np.unique(label[middle]))
    out[got[~keep]] = np.nan
    return out
