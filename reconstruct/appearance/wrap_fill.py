"""Wrap-around appearance: the colours a person would paint on the unseen side of an avatar seen
only from the front. The built-in prior's pseudo-appearance (no learned weights).

Clothes have one base colour and pattern family all round; what the front shows that the sides
do not (a chest print, the face) belongs to the front only. So, per body part, with canonical
positions (the body faces -Y, +Z up):

1. **Boundary band.** The seen Gaussians that lie near the unseen ones -- within ``band`` metres
   (3D) of an unseen Gaussian of the same part -- are the sides the turning body showed: the
   surface that continues round to the unseen side. Their colours are the garment's colours
   *all round*; the middle of the front (where front-only details sit) is not in the band. On a
   part never seen behind its centre (a photo) the band is read next to the unseen Gaussians
   joined to those behind the centre (through unseen Gaussians, at the part's spacing) only: a
   photo's first hits are speckled, and the middle of its front lies next to unseen Gaussians
   too; and the seen region often stops short of the sides, by an angle that differs from
   height to height, so the band is the whole seen edge facing the back, not the few places
   where the seen region reaches within ``band`` of the centre plane. (The head's band stays
   next to its unseen Gaussians behind the centre: the face's sides are not its back.) A torso's
   band there leaves out the seen edge within ``neckline_reach`` of the neck -- over the
   shoulders it runs along the neckline, the front's own -- and a torso whose band is all
   neckline, or all but fewer than 4 ``k``, takes the nearest colours of the other parts.
2. **Low-frequency fill along the wrap direction.** Each unseen Gaussian takes the median colour
   of the ``k`` nearest band Gaussians of its part that lie at the same height (``|Δz| <=
   slab``), widening the slab where there are too few. Patterns periodic in height (stripes that
   wrap round the torso, a belt, a collar, the hairline of the back of the head) are thereby
   carried as functions of height, without the blur of a diffusion over the surface, and the
   back of the head takes the hair of the crown and sides rather than the face.
3. **Mirrored detail, gated.** The mirror image of the unseen Gaussian through the middle, in
   depth, of the part's column through it (same left-right position x and height z;
   ``mirror_column``) is looked up among the seen Gaussians of the part. Its colour is kept
   only when the garment shows that colour round the sides: within ``palette_tolerance`` in each
   RGB channel of some band colour at a nearby height (``|Δz| <= palette_height``). Patterns
   that vary left-right as well (checks) therefore continue with their phase, while a colour
   found only in the middle of the front -- the chest emblem, the face's skin framed by hair --
   is rejected and the low-frequency fill of step 2 stands.
   On the head the band is the seen surface behind the head's centre, less the Gaussians in the
   face's colour cluster (the ears' and the jaw's skin the turning video saw just behind the
   coronal plane) when the head shows hair of its own colour (``hair.py``). Seen from the front
   only (never seen behind its centre: ``behind_share``), the back and the crown take the
   hair's colour instead, when the front shows hair (else the posterior band, if it has ``k``).
   The head's unseen front (a face turned from the camera: its far cheek) takes instead the seen
   colours at its mirror image across the head's midline, left to right (``face_mirror_parts``):
   a face is nearly symmetric, and the hair beside it is not its cheek. The front-only median of
   step 4 leaves those alone.
4. **Smoothing.** A few Jacobi sweeps over the UV grid of the unseen Gaussians (seen ones fixed)
   remove single-texel noise from the median choices. Before them, on a part the video never saw
   behind its centre, whose back has no evidence of a pattern of its own, each unseen Gaussian
   takes the per-channel median of the ``front_only_median`` nearest Gaussians of its part.
   Hair a photo shows fallen over the shoulders is the front's own: on such parts the seen
   Gaussians in the head's hair colours are no source (``hair_over_parts``), and the mirror of
   step 3 gives no colour where its image lies nearer that hair than any source: the nearest
   source there is the hair's edge, blended with the cloth (``hair_over_mirror``).

A part with few seen Gaussians (under ``twin_below``, or under ``twin_share`` of its twin's)
borrows from its left/right twin (mirrored in x); one left with fewer than ``k`` takes the
nearest seen or already filled colours of any part. Before that, a photo's neck and the torso's
front by it, which the chin hides, take what the images show where they lie
(``occluded_parts``, ``occluded_fill.py``).

Parts past the body's (``parts >= len(PART_NAMES)``): a garment layer's Gaussians
(``garment_layer.GARMENT_PART``) are filled as one more part -- its band is the seen cloth round
the tube in the same row (``layer_row_median``), its mirror the same row at theta -> pi - theta
(through the middle of its column, ``mirror_column``), kept only when the band of that row shows
its colour (the layer's rows lie at one height each: ``layer_palette_rows``); it has no left/right
twin and no part rule of the lists below applies to it.
Given the layer's grid, a pattern that repeats round its tube (checks, plaid) is instead carried
on round the unseen side by whole periods (``periodic_fill``). A layer never seen behind its
centre (a photo) is filled by rows instead of by its band and mirror: each row's seen median,
smoothed down the rows where neighbouring rows are alike (``layer_profile_rows``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..avatar.garment_layer import GARMENT_PART, GARMENT_PART_NAME
from ..body.parts import MIRROR, PART_INDEX, PART_NAMES
from .cut_fill import apply_cut_colors
from .hair import face_coloured, hair_and_face, hair_covered, hair_sources, is_warm, skin_reference
from .long_hair import HANG_SHARE, down_the_middle, face_middle, hair_back_colors, hung_from_above, smooth_cover
from .periodic_fill import continue_layer


@dataclass(frozen=True)
class WrapFillConfig:
    band: float = 0.03  # metres: seen Gaussians this close (3D) to an unseen one of the part form the band
    slab: float = 0.01  # metres: half-height of the same-height slab of step 2
    k: int = 8  # band Gaussians whose median colour is taken
    palette_height: float = 0.08  # metres: band colours within this height of the Gaussian form its palette
    palette_tolerance: float = 0.12  # per-channel RGB difference within which a mirrored colour counts as a band colour
    # on a garment layer (given its grid) the palette is the band of the mirrored Gaussian's own
    # row: band colours within this fraction of the layer's row spacing in height (its rows lie at
    # one height each; 0.5 is the row alone). Stripes round a coat put both their colours within
    # ``palette_height`` of every height (coat seed 2: a 10 cm period), so a dark colour of the
    # open front's lining, mirrored to the back, passed the gate between two green stripes and drew
    # a dark band down the back's middle; the row's own band holds only its stripe's colour
    # (coat seed 2 refilled on its Stage I checkpoint: 28.96 -> 29.31 dB unseen at x2, wide
    # trousers seed 2: 28.07 -> 28.16)
    layer_palette_rows: float = 0.5
    # on a garment layer (given its grid) the low-frequency fill (step 2) takes the median of its
    # own row's band -- the row's seen Gaussians nearest to it when that band holds fewer than
    # ``k`` -- not of a slab widened over the rows above and below. A row's band is a column or
    # two each side (``band`` against the layer's 1.4 cm columns), short of ``k``, and the widened
    # slab mixed a stripe with its neighbours: the back of coat seed 2 came out in dulled stripes
    # (refilled on the Stage I checkpoints, unseen at x2: coat seed 2 +0.10 dB, skirt seed 2
    # +0.07, wide trousers seed 2 -0.01, coat seed 1 -0.01, whose checks the periodic fill carries)
    layer_row_median: bool = True
    max_mirror_distance: float = 0.04  # metres: farther mirror matches are not used
    # metres: the mirror of step 3 reflects front to back across the middle, in depth, of the
    # part's column through each unseen Gaussian (its Gaussians within this distance in x and
    # height), not across one plane for the whole part. A torso is deeper at the chest than at the
    # shoulders and leans: on coat seed 1 the upper back's mirror images through the torso's
    # centre plane lay 7-9.5 cm from the chest (the plane 3-5 cm off the middle there), none
    # within ``max_mirror_distance``, and its plaid back took the same-height median of the sides
    # (a flat green). Through the column's middle 71 % lie within it (Stage I checkpoints
    # refinished, x1 unseen: coat seeds 1 / 2 +0.13 / +0.12 dB, skirt seed 2 +0.13, dress seed 0
    # +0.06, tight seeds 0-2 -0.005 / 0.00 / +0.20, wide trousers seeds 0 / 1 -0.05 / -0.04, the
    # one-frame photos 0.00 to +0.02). 0: the part's centre plane
    mirror_column: float = 0.015
    # metres: an unseen Gaussian whose same-height slab holds fewer than ``k`` band Gaussians
    # within this height (the band does not reach its height) takes the median of the ``k``
    # nearest seen Gaussians of its part at its height -- colours the part shows on both sides --
    # instead of a slab widened to the band's nearest heights. On coat seed 1 the torso's band was
    # the chest's seen row along the layer's top (a green stripe, 3 cm high; the shoulders' seen
    # tops lie more than ``band`` from the unseen back), and the plaid upper back above the layer
    # took it at every height. 0: the band only
    band_reach: float = 0.04
    # a part with fewer trusted Gaussians than this takes its left/right twin's (mirrored in x) when
    # the twin has this many: a hand seen as a thin strip keeps a few of its edge's after the
    # erosion, and their colours are the edge's (the long-skirt photo: 8 trusted on the left hand,
    # 6 of them dark where it met the skirt, and its back came out dark red)
    twin_below: int = 32
    # ... and a part with fewer trusted Gaussians than this share of its twin's, however many: what
    # a photo shows of a limb seen far less than its twin is the few texels the fit laid over
    # something else. The green-jacket photo's fitted right upper arm kept 71 trusted texels, 70 of
    # them the white sweater it overlaps (its sleeve was seen only at grazing angles), against 395
    # sleeve-green ones of the left; its back came out white, and the torso's upper back, filled
    # from its neighbours, with it. A pair of sleeves is one garment's
    twin_share: float = 0.25
    # hands a photo hides (folded arms, pockets): one of these parts with fewer than ``twin_below``
    # trusted Gaussians whose sources (its own, or its twin's) are not skin-warm (``hair.is_warm``)
    # takes the face's skin colour (the seen head's face cluster,
    # ``hair.hair_and_face``) when that is warm: the green-coat photo's right hand, under her folded
    # arms, borrowed the left hand's 485 trusted Gaussians, all the coat's green where the fitted
    # hand lay over the coat, and walked as a green mitten. () : off
    hidden_hand_parts: tuple[str, ...] = ("hand.L", "hand.R")
    smooth_sweeps: int = 2
    # parts the video never saw behind their centre (``behind_share``, below: a photo, a video
    # that never turned): their band is the silhouette's sides only,
    # seen at one angle under one light, and the same-height medians carry its folds and shading
    # round as blotches and bands (the coat photo's back). With no evidence of how a pattern
    # continues behind, each unseen Gaussian there takes the per-channel median of this many
    # nearest Gaussians of its part (seen ones included): blotches smaller than its reach go, the
    # colours and boundaries of larger regions stay. (A mean -- 40 Jacobi sweeps -- smoothed as
    # well but blended hair, skin and cloth: a pink patch across the red-dress photo's upper back.)
    # On the synthetic scenes (walking in place, seen behind the torso's centre) it applies to few
    # parts; all parts smoothed by 40 sweeps: tight seed 0 31.80 -> 31.73, coat seed 1 27.06 ->
    # 26.98, dress seed 0 30.82 -> 30.95 dB unseen
    front_only_median: int = 200
    # "never seen behind its centre": fewer than ``k`` reliably seen Gaussians behind the part's
    # centre, or fewer than this share of the part's Gaussians behind it. A photo's silhouette
    # reaches a little behind the centre plane where the surface is not round about it: a flared
    # side of a coat's layer (the coat photo: 81 of the 2,036 behind its centre, 4.0 %), the
    # long-skirt photo's torso (92 of 4,441, 2.1 %). Those are no view of the back, and with ``k``
    # alone such parts took the same-height medians of their sides unsmoothed: the coat photo's
    # layer came out behind in horizontal bands and blotches. The synthetic walks see 8.6-26 %
    # (head 8.6-9.8 %, torso 21-26 %, a wide trousers' layer 12 %); their one-frame photos 0-3.4 %
    # Counted on the part's Gaussians a camera could see: not the body under a garment layer's
    # cloth (``under_layer``). A coat's torso is mostly under its layer, and counted on all its
    # Gaussians the walk's view of its upper back (the layer over the chest) fell under 5 %: coat
    # seed 0 (He init) took the front's green buttons over its upper back, 28.70 -> 26.65 dB unseen.
    # Given the surface normals (``wrap_fill_colors(surface_normals=...)``), only seen Gaussians
    # facing the back count: a torso's upper chest faces the front from behind its mean depth
    behind_share: float = 0.05
    # a garment layer (given its grid) never seen behind its centre -- a photo's skirt or coat --
    # is filled by rows: each unseen Gaussian takes the median colour of its row's seen cloth (the
    # whole row, not its band: the sides of a one-photo garment are its most shaded part), no
    # mirrored colour, and the rows' colours are then averaged over up to ``layer_profile_rows``
    # rows above and below that differ from the row's by at most ``palette_tolerance`` in every
    # channel: shading from row to row goes, stripes stay. The layer is then left out of the
    # front-only median. The band's medians and the mirror, smoothed by the 200 nearest, drew the
    # front's folds, shading and scarf on the back of the coat photo as blotches and bands; on a
    # striped coat the 200 nearest washed the stripes out (the synthetic coat of seed 2 as a
    # one-frame photo: 25.32 -> 26.25 dB unseen). 0: the band, the mirror and the median as for
    # the body's parts
    layer_profile_rows: int = 5
    # ... comparing rows with this share of their mean brightness difference kept (1: every RGB
    # channel as it is): a row darker than its neighbours by much the same amount in each channel
    # is shading, and is averaged with them. The coat photo's top rows, in the shadow of its folded
    # arms (0.15 against 0.29 below), drew a dark line round its back at the layer's top
    layer_profile_luminance: float = 0.5
    # ... each row read on the seen flags before erosion (``wrap_fill_colors(row_seen=...)``) where
    # they cover at least this share of the row's Gaussians in front of the layer's centre, on the
    # eroded flags elsewhere. A row the camera saw as cloth over less of its front is mostly not
    # cloth in the image -- the layer reaching past an open coat's edges or below its front hem --
    # and its few first hits are what shows through: on the green-coat photo the layer's lowest 8
    # rows had 10-12 sources of 45 in front, in the trousers' colour (0.07), and read before
    # erosion they carried a grey band round the coat's back hem (0.27 -> 0.18 rendered). The
    # long-skirt photo's lower rows have 21-39 of 45
    row_seen_share: float = 1 / 3
    # ... and only those in a colour the eroded flags show within this many rows (within
    # ``palette_tolerance`` in every channel): first hits where a sleeve or a hand hangs in front
    # of the cloth are not the cloth's. On the long-skirt photo (prepared again) the sleeves at her
    # hips put two light rows round the back of the skirt's top (0.45 0.49 0.53 against the navy
    # 0.15 0.26 0.42 they now take). None: every colour
    row_seen_rows: int | None = 2
    # parts whose front is not continued by mirroring (step 3 off): the head (the face is the
    # front's own; the back is the hair of the crown and sides) and the feet (the toe cap)
    no_mirror_parts: tuple[str, ...] = ("head", "foot.L", "foot.R")
    # parts whose unseen front takes its seen other side's colours, mirrored left-right through
    # the part's midline (``_left_right_mirror``): a face is nearly symmetric, and a face turned
    # from the camera hides its far cheek. Left to the band and the hair rule, that cheek took
    # the hair beside it: from the side, five of seven photos' faces showed a black or brown
    # cheek. Only in front of the part's centre and only where the mirror image lies within
    # ``face_mirror_reach`` metres of at least 2 seen Gaussians of the part
    face_mirror_parts: tuple[str, ...] = ("head",)
    face_mirror_reach: float = 0.008
    # Seen at grazing incidence is not seen well: a seen Gaussian whose canonical normal makes more
    # than this angle with the direction the video saw the body from (the mean normal of the seen
    # Gaussians) is repainted like an unseen one and is no colour source. Stage I's colours darken
    # towards the silhouette (the fringe blends with the background): on seed 1's garment scene
    # the torso's seen Gaussians are 0.03 darker than the truth facing the camera, 0.06 at 85-95
    # degrees, the thigh's 0.09 and 0.24.
    max_seen_angle_deg: float = 70.0
    # parts whose seen sides count however grazing: the head, whose sides (hair) are seen only at
    # grazing angles and whose frontal part is the face, a front-only detail
    grazing_parts: tuple[str, ...] = ("head",)
    # parts whose unseen side continues the seen surface behind the part's centre only: the back
    # of the head is the hair seen behind the ears, not the skin of the ears and cheeks at the
    # same height (which, carried round, would paint a band of face colour across the back)
    posterior_band_parts: tuple[str, ...] = ("head",)
    # (less those in the face's colour cluster, when the head shows hair: on coat seed 1 the
    # band held two or three ears' skin Gaussians at ear and nape height, and the median of the
    # nape flipped between skin and hair with the training trajectory, front_leak 0.005 / 0.060)
    # ... and when a head has fewer than ``k`` of those (one photo), its back and crown take the
    # colour of the hair the front shows round the face (``hair.py``): rim Gaussians differing
    # from the face's colour by more than ``hair_contrast`` in some channel, at least
    # ``hair_min_share`` of the seen head
    hair_contrast: float = 0.15
    hair_min_share: float = 0.1
    # metres: a Gaussian the hair covers takes the median colour of all the hair Gaussians within
    # this height of it (at least ``k``, the nearest in height), both sides of the head pooled --
    # not of the ``k`` nearest at its height: hair runs down, so what changes from height to height
    # on a photo's rim (a lit strand, a shadowed one) drew horizontal bands across the back of the
    # head (the red-dress photo). 0: the ``k`` nearest at the same height
    hair_slab: float = 0.03
    # ... and at least this share of the hair Gaussians (the nearest in height) where fewer lie
    # within ``hair_slab``. The slab alone left a light line across the back of the grey-skirt
    # photo's dark hair at ear height, where the rim holds few hair Gaussians, some of them lit
    # (the profile there 0.21 0.14 0.09, 0.06-0.11 above and below). A wider slab everywhere
    # (4.5 or 6 cm) smeared a thin hat over hair into the hair below
    hair_profile_share: float = 0.2
    # which of the head's two colour clusters is the face: the one nearer to the seen hands' skin
    # when they tell (``hair.skin_reference``; the middle's vote otherwise). The red-dress photo's
    # middle voted for her shadowed hair, and the back of her head came out skin-coloured
    hair_skin_from_hands: bool = True
    hair_skin_parts: tuple[str, ...] = ("hand.L", "hand.R")
    # parts over which long hair falls in front (a photo): never seen behind their centre, their
    # seen Gaussians in the colours of the hair the head shows (within ``palette_tolerance`` in
    # every channel of one of its hair Gaussians, ``hair.hair_sources``) are no colour source of
    # their back -- but for those in the part's own median colour too (a brown coat under brown
    # hair; the red dress's red, which her hair's rim shows), and unless fewer than ``k`` would be
    # left; nor are they in the front-only median (step 4a). The red-dress photo's blonde hair over
    # both shoulders was carried round her upper back as a brown smear and a dark spot, and one
    # sleeve's back came out maroon (now left out: 269 of the torso's 793 trusted Gaussians, 62 of
    # 175 and 55 of 230 on the upper arms). The front keeps its hair. On the green-coat photo the
    # rule leaves out 558 of the torso's 1,151, its black hair's colours and the coat's darkest
    # shade with them; its back came out nearer the front's green (0.310 0.314 0.251 -> 0.325 0.329
    # 0.267 against 0.329 0.329 0.267) and less blotched
    hair_over_parts: tuple[str, ...] = ("torso", "neck", "upperarm.L", "upperarm.R")
    # ... and the mirror (step 3) gives no colour to an unseen Gaussian whose mirror image lies
    # nearer that hair than any source: the nearest source there is the hair's edge, blended with
    # the cloth (the red-dress photo trained again: 96 Gaussians of the upper back at 0.85 0.34
    # 0.32, a light patch, mirrored from beside the blonde strands over her chest)
    hair_over_mirror: bool = True
    # parts whose band, when never seen behind their centre, leaves out the seen edge within
    # ``neckline_reach`` metres of the neck: over the top of a torso it runs along the neckline (a
    # V-neck's skin, a shirt between an open jacket's lapels), the front's own, and carried round
    # at its height it painted the red-dress photo's upper back with a skin-coloured patch. A back
    # closes higher than a front: the upper back takes the band of the sides below it
    neckline_parts: tuple[str, ...] = ("torso",)
    neckline_reach: float = 0.15
    # the body in no training image (past the edge of a photo that cuts the person off; given
    # ``wrap_fill_colors(cut_colors=...)``) takes the colour the images show where it crosses the
    # edge, one per limb and both limbs of a pair alike (``cut_fill``)
    cut_fill: bool = True
    # a photo's neck and throat, which the chin hides while the images cover them: the unseen
    # Gaussians of these parts (never seen behind their centre) that face the front within
    # ``occluded_reach`` of the neck take what the images show where they project (given
    # ``wrap_fill_colors(occluded_colors=...)``): the throat's skin, a turtleneck's white. Without
    # it the neck (0-14 trusted Gaussians on seven photos) took the nearest filled colour of any
    # part and the throat the band's: a red bib under the red-dress photo's chin in the walk
    occluded_parts: tuple[str, ...] = ("neck", "torso")
    occluded_reach: float = 0.05  # metres from the neck
    # a photo's coat: where the seen upper arms (its sleeves) and the seen garment layer (its skirts)
    # agree in colour (their medians within ``palette_tolerance`` in every channel, each from at least
    # 4 ``k`` Gaussians), the torso's unseen back that the layer leaves visible, never seen behind its
    # centre, takes that colour where its fill differs from it by more than ``palette_tolerance``.
    # An open coat shows what is under it down the middle of the chest, and the torso's band above
    # the layer was that: the group photo's second woman, her brown coat open over a light dress, had
    # a light upper back (0.89 0.73 0.63) under a brown coat (0.70 0.50 0.37)
    coat_back: bool = True
    # ... or where at least this share of the seen upper arms' Gaussians lie within
    # ``palette_tolerance`` of the layer's median (the colour then from those and the layer): a
    # sleeve lit brighter than the skirts, or folded over a scarf, moves its median away. The
    # green-coat photo in greyscale: sleeves 0.43 against the coat's 0.28, 29 % of them within the
    # tolerance, and its upper back came out a lighter grey than the coat; bare arms over a skirt,
    # 0-3 % (five photos), a red dress's sleeves 22 %. 0: the medians only
    coat_arm_share: float = 0.2
    # hair worn down, read in the images (``long_hair_colors``, given as ``wrap_fill_colors(hair_colors=...)``;
    # ``long_hair.py``): the unseen Gaussians of these parts behind their part's centre, on a head
    # seen from the front only, whose twins in front project into the span the hair covers in the
    # images take its colour there (``garment``: a layer over the back, its rows above the torso's
    # middle). The back of a long-haired photo's head ended at the skull, the neck and upper back
    # below it the dress's colour, and the back of blonde hair was its shadowed strands' brown
    hair_back_parts: tuple[str, ...] = ("head", "neck", "torso", GARMENT_PART_NAME)


def grazing_rule_for(stage1_settings) -> bool:
    """Whether the ``max_seen_angle_deg`` rule applies to an avatar trained with these Stage I
    settings: only with one fixed background, whose blend darkens the silhouette's colours. An
    avatar trained on random backgrounds (``random_background``) keeps its grazing colours true,
    and repainting them loses detail (seed 0, 10 minutes: unseen 28.59 dB as filled with the rule,
    29.26 without; Stage II's pseudo-appearance painted on: 26.11 with it, 29.19 without)."""
    return not getattr(stage1_settings, "random_background", False)


def _per_gaussian(colours, n: int, name: str) -> np.ndarray | None:
    """``colours`` as an (n,3) array (NaN where none), or None; ValueError naming ``name`` otherwise."""
    if colours is None:
        return None
    out = _as_np(colours)
    if out.shape != (n, 3):
        raise ValueError(f"wrap_fill_colors: {name} must have shape ({n}, 3), found {out.shape}")
    return out


def _as_np(x, dtype=np.float64) -> np.ndarray:
    if isinstance(x, torch.Tensor):
        x = x.detach().cpu().numpy()
    return np.asarray(x, dtype)


def _slab(z_sorted: np.ndarray, z: float, cfg: WrapFillConfig, widest: float | None = None) -> tuple[int, int, float]:
    """The same-height slab round ``z`` in sorted heights: (lo, hi, half-height), the half-height
    from ``slab`` doubled up to 8 times until the slab holds ``k`` (or all); with ``widest``, no
    wider than that (then it may hold fewer than ``k``)."""
    slab = cfg.slab
    for _ in range(8):
        lo, hi = np.searchsorted(z_sorted, z - slab), np.searchsorted(z_sorted, z + slab, side="right")
        if hi - lo >= cfg.k or (lo == 0 and hi == len(z_sorted)) or (widest is not None and 2 * slab > widest):
            break
        slab *= 2
    return lo, hi, slab


def _same_height_median(pos_q: np.ndarray, pos_b: np.ndarray, col_b: np.ndarray, cfg: WrapFillConfig,
                        seen_row: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Median colour of the ``k`` band Gaussians nearest to each query among those at the same
    height (the slab widened x2 up to 8 times where it holds fewer than ``k``). ``seen_row``: the
    part's seen (positions, colours); a query whose band slab must be wider than ``band_reach``
    takes the ``k`` of these nearest at its height instead, when they hold ``k`` within it."""
    out = np.empty((len(pos_q), 3))
    if len(pos_b) == 0:
        return out * np.nan
    order = np.argsort(pos_b[:, 2])
    zb = pos_b[order, 2]
    reach = cfg.band_reach if seen_row is not None and len(seen_row[0]) >= cfg.k else 0.0
    if reach > 0:
        s_order = np.argsort(seen_row[0][:, 2])
        zs = seen_row[0][s_order, 2]
    for i, q in enumerate(pos_q):
        lo, hi, slab = _slab(zb, q[2], cfg)
        pos_s, col_s, idx = pos_b, col_b, (order[lo:hi] if hi > lo else order)
        if reach > 0 and (slab > reach or hi - lo < cfg.k):
            s_lo, s_hi, s_slab = _slab(zs, q[2], cfg, widest=reach)
            if s_hi - s_lo >= cfg.k and s_slab <= reach:
                pos_s, col_s, idx = seen_row[0], seen_row[1], s_order[s_lo:s_hi]
        d = np.linalg.norm(pos_s[idx] - q, axis=1)
        out[i] = np.median(col_s[idx[np.argsort(d)[: cfg.k]]], axis=0)
    return out


def height_profile(z_query: np.ndarray, z_src: np.ndarray, col_src: np.ndarray, slab: float, k: int) -> np.ndarray:
    """(Q,3): for each query height the per-channel median colour of the sources (heights
    ``z_src``, colours ``col_src``) within ``slab`` of it in height, or of the ``k`` nearest to it
    in height where fewer lie within; NaN without sources."""
    out = np.full((len(z_query), 3), np.nan)
    if len(z_src) == 0:
        return out
    order = np.argsort(z_src)
    zs, cs = np.asarray(z_src)[order], np.asarray(col_src, np.float64)[order]
    lo = np.searchsorted(zs, z_query - slab)
    hi = np.searchsorted(zs, z_query + slab, side="right")
    kk = min(k, len(zs))
    for i, z in enumerate(z_query):
        if hi[i] - lo[i] >= kk:
            out[i] = np.median(cs[lo[i]:hi[i]], axis=0)
        else:
            near = np.argsort(np.abs(zs - z), kind="stable")[:kk]
            out[i] = np.median(cs[near], axis=0)
    return out


def _reaching_back(pos_unseen: np.ndarray, behind: np.ndarray, spacing: float) -> np.ndarray:
    """(len(pos_unseen),) bool: the unseen Gaussians joined to one behind the part's centre
    (``behind``, bool) through unseen Gaussians no farther apart than 1.5 ``spacing`` (diagonal
    neighbours on a grid of that spacing) -- the unseen side and the strips that lead to it, not
    the speckles inside a photo's seen front."""
    pairs = cKDTree(pos_unseen).query_pairs(1.5 * spacing, output_type="ndarray")
    n = len(pos_unseen)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    return np.isin(label, np.unique(label[behind]))


def _row_median(rows_q: np.ndarray, pos_q: np.ndarray, rows_b: np.ndarray, pos_b: np.ndarray,
                col_b: np.ndarray, rows_s: np.ndarray, pos_s: np.ndarray, col_s: np.ndarray,
                k: int) -> np.ndarray:
    """Median colour of the ``k`` Gaussians nearest to each query among the band Gaussians of its
    own grid row (``rows_*``: row indices), or among the row's seen Gaussians (``*_s``) when its band
    holds fewer than ``k``; NaN for a query whose row has no seen Gaussian."""
    out = np.full((len(pos_q), 3), np.nan)
    for r in np.unique(rows_q):
        q = rows_q == r
        b = rows_b == r
        pos, col = (pos_b[b], col_b[b]) if b.sum() >= k else (pos_s[rows_s == r], col_s[rows_s == r])
        if len(pos) == 0:
            continue
        kk = min(k, len(pos))
        _, nn = cKDTree(pos).query(pos_q[q], k=kk)
        out[q] = np.median(col[np.asarray(nn).reshape(q.sum(), kk)], axis=1)
    return out


def _row_profile(rows: np.ndarray, colours: np.ndarray, reach: int, tolerance: float,
                 luminance: float = 1.0) -> np.ndarray:
    """Each row's colour (the queries of a row share one; NaN rows are left alone) averaged with
    those of the rows within ``reach`` rows of it that differ from it by at most ``tolerance`` in
    every channel once ``1 - luminance`` of their mean difference is taken off: an edge-preserving
    smoothing down the layer (shading goes, stripes stay)."""
    out = colours.copy()
    ok = np.isfinite(colours).all(1)
    ids = np.unique(rows[ok])
    if len(ids) == 0:
        return out
    value = np.stack([colours[ok & (rows == r)][0] for r in ids])
    for i, r in enumerate(ids):
        diff = value - value[i]
        diff -= (1.0 - luminance) * diff.mean(1, keepdims=True)
        near = (np.abs(ids - r) <= reach) & (np.abs(diff).max(1) <= tolerance)
        out[ok & (rows == r)] = value[near].mean(0)
    return out


def column_middle(part_pos: np.ndarray, query: np.ndarray, radius: float, fallback: float) -> np.ndarray:
    """(M,) the depth (y) halfway between the front-most and the back-most of ``part_pos`` (N,3)
    within ``radius`` of each ``query`` (M,3) in x and height (z): the middle of the part's column
    through it, the plane its front is mirrored across there. ``fallback`` where the column holds
    fewer than two."""
    out = np.full(len(query), float(fallback))
    if len(part_pos) < 2 or len(query) == 0:
        return out
    balls = cKDTree(part_pos[:, [0, 2]]).query_ball_point(query[:, [0, 2]], radius)
    counts = np.fromiter(map(len, balls), np.int64, len(balls))
    full = np.flatnonzero(counts >= 2)
    if len(full):
        y = part_pos[np.concatenate([balls[i] for i in full]).astype(np.int64), 1]
        starts = np.r_[0, np.cumsum(counts[full])[:-1]]
        out[full] = 0.5 * (np.minimum.reduceat(y, starts) + np.maximum.reduceat(y, starts))
    return out


def _joint(col: np.ndarray, z: np.ndarray, cfg: WrapFillConfig, height: float | None = None) -> np.ndarray:
    """(colour, height scaled so that ``height`` (default palette_height) maps to palette_tolerance):
    a box query with the max-norm is then "within the tolerance in every channel and within the
    height"."""
    return np.c_[col, z[:, None] * (cfg.palette_tolerance / (cfg.palette_height if height is None else height))]


def _layer_row_spacing(layer_pos: np.ndarray, rows: int) -> float | None:
    """The median height between consecutive rows of a garment layer's row-major Gaussians
    (``rows`` rows of equal length); None when it has fewer than two rows or they do not step in
    height."""
    if rows < 2:
        return None
    z = layer_pos[:, 2].reshape(rows, -1).mean(1)
    step = float(np.median(np.abs(np.diff(z))))
    return step if step > 0 else None


def _never_seen_behind(pos: np.ndarray, members: np.ndarray, src: np.ndarray, visible: np.ndarray,
                       surf: np.ndarray | None, cfg: WrapFillConfig) -> bool:
    """Whether a part (``members``; ``src`` its seen ones) was never seen behind its centre
    (``behind_share``): fewer than ``k`` of ``src`` lie behind its centre -- facing the back, given
    the surface normals ``surf`` -- or fewer than ``behind_share`` of its ``visible`` Gaussians
    there."""
    centre_y = pos[members, 1].mean()
    behind = pos[src, 1] > centre_y
    if surf is not None:  # and facing the back: a front lying behind the centre plane is no view of it
        behind &= surf[src, 1] > 0
    behind_visible = (pos[members, 1] > centre_y) & visible[members]
    return bool(behind.sum() < max(cfg.k, cfg.behind_share * behind_visible.sum()))


def _left_right_mirror(todo_pos: np.ndarray, src_pos: np.ndarray, src_col: np.ndarray, centre_x: float,
                       centre_y: float, reach: float, k: int = 4) -> np.ndarray:
    """(T,3): for each unseen Gaussian in front of the part's centre (y below ``centre_y``; the
    body faces -Y) the per-channel median colour of the seen Gaussians (``src_pos``,
    ``src_col``) within ``reach`` of its mirror image across the plane x = ``centre_x`` (at most
    the ``k`` nearest, at least 2); NaN elsewhere (``WrapFillConfig.face_mirror_parts``)."""
    out = np.full((len(todo_pos), 3), np.nan)
    front = np.flatnonzero(todo_pos[:, 1] < centre_y)
    if len(front) == 0 or len(src_pos) < 2:
        return out
    query = todo_pos[front] * np.array([-1.0, 1.0, 1.0]) + np.array([2 * centre_x, 0.0, 0.0])
    k = min(k, len(src_pos))
    dist, idx = cKDTree(src_pos).query(query, k=k, distance_upper_bound=reach)
    dist, idx = dist.reshape(len(front), k), idx.reshape(len(front), k)
    near = np.isfinite(dist)
    enough = near.sum(1) >= 2
    cols = np.where(near[..., None], src_col[np.minimum(idx, len(src_pos) - 1)], np.nan)  # misses: NaN
    out[front[enough]] = np.nanmedian(cols[enough], axis=1)
    return out


# parts hair worn down does not fall over: their seen colours are what the hair is told from
HAIR_FREE_PARTS: tuple[str, ...] = ("lowerarm.L", "lowerarm.R", "hand.L", "hand.R")


def _front_hair(pos: np.ndarray, col: np.ndarray, parts: np.ndarray, seen: np.ndarray,
                hair_seen: np.ndarray, skin: np.ndarray | None, cfg: WrapFillConfig,
                visible: np.ndarray, surf: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray] | None:
    """(hair, face): indices of the Gaussians that show the hair round the face of a head seen from
    the front (``hair.hair_and_face`` on its ``hair_seen`` Gaussians: strands lit and shadowed
    alike) and of those in the face's colours, or None: no head, no hair of its own colour, or a
    head seen behind its centre (a video that turned; ``_never_seen_behind`` on ``seen``, as the
    fill decides it)."""
    if "head" not in PART_INDEX:
        return None
    members = np.flatnonzero(parts == PART_INDEX["head"])
    if len(members) < cfg.k or not _never_seen_behind(pos, members, members[seen[members]], visible, surf, cfg):
        return None
    centre = pos[members].mean(0)
    src = members[hair_seen[members]]
    if len(src) < cfg.k:
        return None
    split = hair_and_face(pos[src], col[src], centre[0], contrast=cfg.hair_contrast, min_share=cfg.hair_min_share,
                          k=cfg.k, skin=skin)
    if split is None or split[0].sum() < cfg.k:
        return None
    return src[split[0]], src[split[1]]


def _hair_coloured(src_col: np.ndarray, palette: np.ndarray, cfg: WrapFillConfig) -> np.ndarray:
    """(M,) bool: the sources within ``palette_tolerance`` in every channel of some colour of the
    hair's ``palette`` and not of the part's own median colour (``hair_over_parts``); none when
    fewer than ``k`` sources would be left (a part with none seen among them)."""
    if len(src_col) <= cfg.k:
        return np.zeros(len(src_col), bool)
    like = cKDTree(palette).query(src_col, p=np.inf)[0] <= cfg.palette_tolerance
    like &= np.abs(src_col - np.median(src_col, 0)).max(1) > cfg.palette_tolerance
    return like if (~like).sum() >= cfg.k else np.zeros(len(src_col), bool)


def _cloth_row_sources(members: np.ndarray, seen: np.ndarray, row_seen: np.ndarray, pos: np.ndarray,
                       col: np.ndarray, centre_y: float, layer_grid: tuple[int, int, int],
                       cfg: WrapFillConfig) -> np.ndarray:
    """The sources a photo's garment layer (``members``, row-major on ``layer_grid``) reads its rows
    on: ``seen`` (eroded), and ``row_seen`` (before erosion) in the rows whose first hits cover at
    least ``row_seen_share`` of their Gaussians in front of the layer's centre ``centre_y``, in
    colours the eroded flags show within ``row_seen_rows`` rows (not an arm's or a top's hanging in
    front of the cloth)."""
    row_m = (members - members[0]) // layer_grid[1]
    front_n = np.bincount(row_m[pos[members, 1] < centre_y], minlength=layer_grid[0])
    loose_n = np.bincount(row_m[row_seen[members]], minlength=layer_grid[0])
    cloth_row = loose_n >= np.maximum(1.0, cfg.row_seen_share * front_n)
    own = seen[members]
    extra = cloth_row[row_m] & row_seen[members] & ~own
    if cfg.row_seen_rows is not None and extra.any() and own.any():
        height = max(cfg.row_seen_rows, 1e-9)  # in rows: 0 is the row alone
        d, _ = cKDTree(_joint(col[members[own]], row_m[own], cfg, height)).query(
            _joint(col[members[extra]], row_m[extra], cfg, height), p=np.inf)
        extra[np.flatnonzero(extra)[d > cfg.palette_tolerance]] = False
    return members[own | extra]


def _on_both_sides(band_pos: np.ndarray, band_col: np.ndarray, centre_x: float, cfg: WrapFillConfig) -> np.ndarray:
    left = band_pos[:, 0] < centre_x
    keep = np.zeros(len(band_pos), bool)
    if left.all() or not left.any():
        return ~keep
    for side in (left, ~left):
        other = cKDTree(_joint(band_col[~side], band_pos[~side, 2], cfg))
        d, _ = other.query(_joint(band_col[side], band_pos[side, 2], cfg), p=np.inf)
        keep[side] = d <= cfg.palette_tolerance
    return keep


def reliable_seen(seen: np.ndarray, normals: np.ndarray | None, parts: np.ndarray,
                  config: WrapFillConfig = WrapFillConfig()) -> np.ndarray:
    """The seen Gaussians whose colour is trusted as a source: not seen at grazing incidence only
    (see ``max_seen_angle_deg``; the direction the video saw the body from is the mean canonical
    normal of the seen Gaussians). Without normals: ``seen``."""
    seen = np.asarray(seen, bool)
    if normals is None or not seen.any():
        return seen
    n = np.asarray(normals, np.float64)
    v = n[seen].mean(0)
    if np.linalg.norm(v) < 1e-6:
        return seen
    facing = n @ (v / np.linalg.norm(v))
    ok = facing >= np.cos(np.radians(config.max_seen_angle_deg))
    ok |= np.isin(parts, [PART_INDEX[p] for p in config.grazing_parts if p in PART_INDEX])
    return seen & ok


def _facing_front(pos: np.ndarray, surf: np.ndarray | None, idx: np.ndarray, centre_y: float) -> np.ndarray:
    """(len(idx),) bool: which of the Gaussians ``idx`` lie on the front of the body (the avatar
    faces -y): their surface normal points forwards when ``surf`` (N,3) is given, else they lie in
    front of ``centre_y``. On a torso the normal tells: its upper back by the neck lies ahead of
    the torso's mean depth."""
    if surf is not None:
        return surf[idx, 1] < 0
    return pos[idx, 1] < centre_y


def _from_the_images(out: np.ndarray, filled: np.ndarray, from_images: np.ndarray, pos: np.ndarray,
                     parts: np.ndarray, keep: np.ndarray, surf: np.ndarray | None, occluded: np.ndarray,
                     cfg: WrapFillConfig) -> None:
    """``WrapFillConfig.occluded_parts``, in place: the Gaussians of those parts not in ``keep``
    that face the front within ``occluded_reach`` of the neck take their ``occluded`` colour where
    they have one, and the rest of them the nearest of those; each part on its own."""
    neck = parts == PART_INDEX["neck"]
    if not neck.any():
        return
    tree = cKDTree(pos[neck])
    for name in cfg.occluded_parts:
        p = PART_INDEX.get(name, -1)
        members = np.flatnonzero((parts == p) & ~keep)
        if len(members) == 0:
            continue
        near = tree.query(pos[members])[0] <= cfg.occluded_reach
        todo = members[near & _facing_front(pos, surf, members, pos[parts == p, 1].mean())]
        read = np.isfinite(occluded[todo]).all(1)
        got = todo[read]
        if len(got) == 0:
            continue
        out[got] = occluded[got]
        rest = todo[~read]
        if len(rest):
            _, nn = cKDTree(pos[got]).query(pos[rest])
            out[rest] = occluded[got[nn]]
        filled[todo] = True
        from_images[todo] = True


def coat_colour(col: np.ndarray, parts: np.ndarray, seen: np.ndarray, cfg: WrapFillConfig) -> np.ndarray | None:
    """(3,) the colour a coat shows on its sleeves and below the waist: the median of the seen upper
    arms and garment layer together when each holds at least 4 ``k`` seen Gaussians and their medians
    agree within ``palette_tolerance`` in every channel, or, failing that, of the layer and the arms'
    Gaussians within that of the layer's median when they are at least ``coat_arm_share`` of the
    arms' (and ``k``); else None (no layer, bare arms, a top and a skirt of two colours)."""
    arms = np.isin(parts, [PART_INDEX["upperarm.L"], PART_INDEX["upperarm.R"]]) & seen
    layer = (parts == GARMENT_PART) & seen
    if arms.sum() < 4 * cfg.k or layer.sum() < 4 * cfg.k:
        return None
    skirts = np.median(col[layer], 0)
    if not (np.abs(np.median(col[arms], 0) - skirts) > cfg.palette_tolerance).any():
        return np.median(col[arms | layer], 0)
    # part of the sleeves in the skirts' colour (``coat_arm_share``)
    arm_ids = np.flatnonzero(arms)
    near = (np.abs(col[arm_ids] - skirts) <= cfg.palette_tolerance).all(1)
    if cfg.coat_arm_share <= 0 or near.sum() < cfg.k or near.mean() < cfg.coat_arm_share:
        return None
    return np.median(np.r_[col[arm_ids[near]], col[layer]], 0)


def _hair_down_the_back(pos: np.ndarray, parts: np.ndarray, seen: np.ndarray, done: np.ndarray,
                        front_hair: tuple[np.ndarray, np.ndarray], views, cfg: WrapFillConfig,
                        neighbours: np.ndarray | None) -> np.ndarray:
    """(N,3): for the unseen (not ``done``) Gaussians of ``hair_back_parts`` behind their part's
    centre that the hair in the images covers, its colour there (``long_hair.hair_back_colors``);
    NaN for the others. The colours the hair is told from: the face's skin (its middle's seen
    Gaussians in the face's colours), the clothes of the torso's lower half and of the garment
    layer beside it, and the ``HAIR_FREE_PARTS`` (the forearms and hands), all ``seen``."""
    none = np.full((len(pos), 3), np.nan, np.float32)
    torso = parts == PART_INDEX.get("torso", -1)
    if not torso.any():
        return none
    middle = 0.5 * (pos[torso, 2].min() + pos[torso, 2].max())
    behind, twins = [], []
    for name in cfg.hair_back_parts:
        if name == GARMENT_PART_NAME:  # a garment layer over the back: its rows above the torso's middle,
            members = np.flatnonzero((parts == GARMENT_PART) & (pos[:, 2] >= middle))  # by the torso's centre
            centre_y = pos[torso, 1].mean()
        elif name in PART_INDEX:
            members = np.flatnonzero(parts == PART_INDEX[name])
            centre_y = pos[members, 1].mean() if len(members) else 0.0
        else:
            continue
        todo = members[~done[members]]
        back = todo[pos[todo, 1] > centre_y]
        front = members[pos[members, 1] <= centre_y]
        if len(back) and len(front):  # each one's twin: the front's Gaussian at its left-right place and height
            behind.append(back)
            twins.append(front[cKDTree(pos[front][:, [0, 2]]).query(pos[back][:, [0, 2]])[1]])
    candidates = np.concatenate(behind) if behind else np.zeros(0, np.int64)
    if not len(candidates):
        return none
    free = np.isin(parts, [PART_INDEX[n] for n in HAIR_FREE_PARTS if n in PART_INDEX])
    # the torso's and a garment layer's lower half: down to the torso's bottom (trousers and shoes
    # are no rivals: black trousers hid a photo's black hair)
    waist = np.isin(parts, [PART_INDEX["torso"], GARMENT_PART]) & (pos[:, 2] < middle) & (pos[:, 2] >= pos[torso, 2].min())
    head = np.flatnonzero(parts == PART_INDEX["head"])
    face = head[face_middle(pos[head])]
    hair_idx, face_coloured_idx = front_hair
    rivals = [np.intersect1d(face, face_coloured_idx), np.flatnonzero(seen & (waist | free))]
    hair = hair_back_colors(len(pos), candidates, hair_idx, face, rivals, views, tolerance=cfg.palette_tolerance,
                            hanging=parts[candidates] != PART_INDEX["head"],
                            neck=np.flatnonzero(parts == PART_INDEX.get("neck", -1)), twins=np.concatenate(twins))
    if neighbours is not None:
        hair = smooth_cover(hair, candidates, neighbours)
    middle_x = float(np.median(pos[face, 0])) if len(face) else float(pos[head, 0].mean())
    for group in behind:
        if parts[group[0]] in (PART_INDEX.get("torso"), GARMENT_PART):
            hair = down_the_middle(hair, group, pos, middle_x)
    # a part below the head is covered only below a covered one; a layer over the back only where the
    # back above it is covered at all (the back's candidates stop at the layer's top)
    return hung_from_above(hair, behind, [0.0 if parts[g[0]] == PART_INDEX.get("torso") else HANG_SHARE for g in behind])


@dataclass
class _Given:
    """``wrap_fill_colors``' inputs as arrays, checked: the reliable ``seen`` flags, the hair's
    (``hair_seen``, or None), the surface normals (``surf``, or None), a garment layer's cover of the
    body (``ul``, or None) and what a camera could see (``visible``: not the body under the cloth)."""

    pos: np.ndarray
    col: np.ndarray
    parts: np.ndarray
    seen: np.ndarray
    hair_seen: np.ndarray | None
    surf: np.ndarray | None
    ul: np.ndarray | None
    visible: np.ndarray


def _given(positions, parts, seen, colors, normals, hair_seen, surface_normals, under_layer, cfg: WrapFillConfig) -> _Given:
    pos = _as_np(positions)
    parts = np.asarray(parts)
    seen = reliable_seen(_as_np(seen, bool), None if normals is None else _as_np(normals), parts, cfg)
    surf = None if surface_normals is None else _as_np(surface_normals)
    if surf is not None and surf.shape != (len(pos), 3):
        raise ValueError(f"wrap_fill_colors: surface_normals must have shape ({len(pos)}, 3), found {surf.shape}")
    ul = None
    if under_layer is not None:
        ul = np.asarray(under_layer, np.int64)
        if ul.shape != (len(pos),):
            raise ValueError(f"wrap_fill_colors: under_layer must have shape ({len(pos)},), found {ul.shape}")
    return _Given(pos, _as_np(colors), parts, seen, None if hair_seen is None else _as_np(hair_seen, bool) | seen,
                  surf, ul, np.ones(len(pos), bool) if ul is None else ul < 0)


def _skin_and_front_hair(g: _Given, cfg: WrapFillConfig):
    """(the hands' skin colour or None, ``_front_hair`` or None): which of the head's colour clusters
    is the face (``hair.py``), and the hair a photo's head shows round the face."""
    skin = None
    if cfg.hair_skin_from_hands:
        hands = np.isin(g.parts, [PART_INDEX[n] for n in cfg.hair_skin_parts if n in PART_INDEX]) & g.seen
        skin = skin_reference(g.col[hands])
    return skin, _front_hair(g.pos, g.col, g.parts, g.seen, g.seen if g.hair_seen is None else g.hair_seen, skin, cfg,
                             g.visible, g.surf)


def long_hair_colors(positions, parts, seen, colors, views, neighbours: np.ndarray | None = None,
                     config: WrapFillConfig = WrapFillConfig(), normals=None, under_layer=None, hair_seen=None,
                     surface_normals=None) -> torch.Tensor:
    """(N,3) float32: hair worn down, read in the training frames ``views`` (``cut_fill.FrameView``s,
    iterated once, and only when a head seen from the front shows hair of its own colour;
    ``long_hair.py``): for the unseen Gaussians of ``hair_back_parts`` behind their part's centre
    that it covers, its colour; NaN for the others. The arguments as ``wrap_fill_colors``', which
    takes the result as ``hair_colors`` (Stage I's finish keeps it: ``AvatarState.hair_colors``)."""
    cfg = config
    g = _given(positions, parts, seen, colors, normals, hair_seen, surface_normals, under_layer, cfg)
    none = torch.full((len(g.pos), 3), float("nan"))
    if not cfg.hair_back_parts or not g.seen.any() or g.seen.all():
        return none
    _, front_hair = _skin_and_front_hair(g, cfg)
    if front_hair is None:
        return none
    return torch.as_tensor(_hair_down_the_back(g.pos, g.parts, g.seen, g.seen | ~g.visible, front_hair, views, cfg,
                                               neighbours), dtype=torch.float32)


def wrap_fill_colors(positions, parts, seen, colors, neighbours: np.ndarray | None = None,
                     config: WrapFillConfig = WrapFillConfig(), normals=None, no_mirror=None,
                     under_layer=None, layer_grid: tuple[int, int, int] | None = None,
                     hair_seen=None, surface_normals=None, cut_colors=None, row_seen=None,
                     occluded_colors=None, hair_colors=None) -> torch.Tensor:
    """(N,3) float32 colours: the reliably seen Gaussians' own, the others (unseen, or seen only
    at grazing incidence when ``normals`` are given) filled as described in the module docstring.
    ``positions``, ``normals``: canonical (N,3); ``parts``: (N,) body-part indices; ``seen``: (N,)
    bool (the trusted flags); ``neighbours``: ``texel_neighbours`` of the Gaussians' texels (for
    the smoothing; None skips it). ``no_mirror``: (N,) bool, Gaussians that take the
    low-frequency fill only, never a mirrored colour (regions a user asked to redo).
    ``under_layer``: (N,) int, for the body Gaussians a garment layer's cloth hides the index of the
    layer Gaussian that hides each (``layer_cover.model_body_under_layer``), -1 elsewhere: those not
    reliably seen take that layer Gaussian's filled colour, so that what shows through the cloth
    (an offset or a pose bringing the body through it, the gaps between its Gaussians) is the cloth.
    ``layer_grid``: (rows, cols, tubes) of a garment layer whose Gaussians are the part
    ``GARMENT_PART``, row-major: a pattern repeating round its tube is carried on round the unseen
    side by whole periods (``periodic_fill``) instead of mirrored, and kept out of the smoothing.
    ``hair_seen``: (N,) bool, seen flags eroded less than ``seen`` (1 texel against 2): a head seen
    from the front only reads its hair on them (``hair.py``). The hair framing a face is a ring a
    few texels wide, and erosion took most of it (the red-dress photo's hair rule stood down and the
    back of her head came out bald). ``row_seen``: (N,) bool, the seen flags before any erosion: a
    garment layer filled by rows (a photo's, ``layer_profile_rows``) reads each row's seen cloth on
    them. A photo's first hits on the cloth are speckled, the light ones (sheen, the matte's
    fringe) most, and erosion by 2 texels kept the dark folds between them: the long-skirt photo's
    lower rows kept 5-25 of their 25-42 seen front Gaussians, their blue at half the seen ones'
    median, and the back of its navy skirt rendered near black, (0.012, 0.012, 0.031) at the knees
    against the front's (0.035, 0.043, 0.100); read before erosion, (0.024, 0.035, 0.090). Only in
    rows the camera saw as cloth (``row_seen_share``) and in colours the eroded flags show nearby
    (``row_seen_rows``).
    ``surface_normals``: (N,3) canonical normals of the surface each
    Gaussian sits on; given, a seen Gaussian behind its part's centre counts as a view of the back
    (``behind_share``) only where its normal faces the back (+Y). A torso's upper chest and shoulders
    face the front from behind the torso's mean depth (its belly lies in front): on a coat photo
    cut at the knees, 69 front-facing Gaussians there (5.3 % of its visible back) took the torso
    for seen behind, and its upper back took the same-height medians of the hair, the collar and
    the scarf round the shoulders as blotches instead of the front-only median. ``cut_colors``:
    (N,3), NaN but for the Gaussians in no training image (``AvatarState.cut_colors``): the body's
    unseen ones among them take it (``cut_fill``, ``WrapFillConfig.cut_fill``)."""
    cfg = config
    no_mirror = None if no_mirror is None else _as_np(no_mirror, bool)
    g = _given(positions, parts, seen, colors, normals, hair_seen, surface_normals, under_layer, cfg)
    pos, col, parts, seen, hair_seen, surf, ul, visible = g.pos, g.col, g.parts, g.seen, g.hair_seen, g.surf, g.ul, g.visible
    if row_seen is not None:
        row_seen = _as_np(row_seen, bool)
        if row_seen.shape != seen.shape:
            raise ValueError(f"wrap_fill_colors: row_seen must have shape {seen.shape}, found {row_seen.shape}")
        row_seen = reliable_seen(row_seen, None if normals is None else _as_np(normals), parts, cfg) | seen
    occluded = _per_gaussian(occluded_colors, len(pos), "occluded_colors")
    hair_back = _per_gaussian(hair_colors, len(pos), "hair_colors")
    out = col.copy()
    unseen_all = np.flatnonzero(~seen)
    if len(unseen_all) == 0 or not seen.any():
        return torch.as_tensor(np.clip(out, 0, 1), dtype=torch.float32)
    filled = np.zeros(len(pos), bool)
    front_only = np.zeros(len(pos), bool)  # unseen Gaussians of parts never seen behind their centre
    periodic = np.zeros(len(pos), bool)  # unseen Gaussians a repeating pattern was carried onto
    layer_rows_only = np.zeros(len(pos), bool)  # a front-only layer filled by rows (``layer_profile_rows``)
    neckline_only: list[int] = []  # parts whose band was all neckline: filled from their neighbours
    # the hands' colour (which of the head's colour clusters is the face) and the hair a photo's head
    # shows round the face: its colours for the parts it falls over (``hair_over_parts``)
    skin, front_hair = _skin_and_front_hair(g, cfg)
    hair_palette = None if front_hair is None or not cfg.hair_over_parts else col[front_hair[0]]
    face_skin = None  # the face's colour, for hands a photo hid (``hidden_hand_parts``)
    if front_hair is not None and cfg.hidden_hand_parts and len(front_hair[1]):
        face_skin = np.median(col[front_hair[1]], axis=0)
        face_skin = face_skin if is_warm(face_skin) else None
    over_hair = np.zeros(len(pos), bool)  # seen Gaussians in the hair's colour that are no source
    mirrored_across = np.zeros(len(pos), bool)  # a face's unseen front given its other side (``face_mirror_parts``)
    from_images = np.zeros(len(pos), bool)  # unseen Gaussians given what the images show there (``occluded_parts``)
    for p in np.unique(parts):
        members = np.flatnonzero(parts == p)
        todo = members[~seen[members]]
        if len(todo) == 0:
            continue
        name = PART_NAMES[p] if p < len(PART_NAMES) else ""  # "" for a garment layer
        # a garment layer given with its grid: members are in index order, its row-major grid
        on_grid = layer_grid is not None and p == GARMENT_PART and len(members) == layer_grid[0] * layer_grid[1]
        centre_y = pos[members, 1].mean()
        src = members[seen[members]]
        never_behind = _never_seen_behind(pos, members, src, visible, surf, cfg)
        front_only[todo] = never_behind
        # a photo's garment layer: filled by rows, no band, no mirror (``layer_profile_rows``)
        by_rows = on_grid and cfg.layer_row_median and never_behind and cfg.layer_profile_rows > 0
        if never_behind and hair_palette is not None and name in cfg.hair_over_parts:
            hair_like = _hair_coloured(col[src], hair_palette, cfg)
            over_hair[src[hair_like]] = True
            src = src[~hair_like]
        src_pos = pos[src] if len(src) else np.zeros((0, 3))
        twin_min = max(cfg.k, cfg.twin_below)
        twin = PART_INDEX.get(MIRROR.get(name, ""), -1)
        if twin >= 0 and twin != p:  # borrow the left/right twin, mirrored in x
            tw = np.flatnonzero((parts == twin) & seen)
            if len(tw) >= twin_min and (len(src) < twin_min or len(src) < cfg.twin_share * len(tw)):
                src = tw
                src_pos = pos[tw] * np.array([-1.0, 1.0, 1.0])
        if name in cfg.hidden_hand_parts and (seen[members].sum() < twin_min) and face_skin is not None:
            if not len(src) or not is_warm(np.median(col[src], axis=0)):  # a hand the photo hid
                out[todo] = face_skin
                filled[todo] = True
                continue
        if len(src) < cfg.k:
            continue  # left to the fallback below
        # 1. the boundary band: seen Gaussians of the part near its unseen ones -- on a part never
        # seen behind its centre, near the unseen ones joined to those behind the centre (module
        # docstring, step 1). Not near isolated unseen ones: a photo's speckled front (an open
        # jacket's shirt) is the nearest seen colour to a flat torso's back. Not only near those
        # behind the centre: the long-skirt photo's band was then 43 Gaussians at the skirt's top
        # on one side, and painted the upper half of its back. The head keeps the unseen ones
        # behind its centre: the face's sides are not its back (the sweater photo's bent head
        # took the cheek's skin round)
        near = todo
        behind = pos[todo, 1] > centre_y
        posterior = name in cfg.posterior_band_parts
        if never_behind and behind.sum() >= cfg.k:
            if posterior:
                near = todo[behind]
            else:
                # the spacing across both directions of the surface: on a grid the 4th nearest
                # neighbour is the farther of the row and column neighbours
                kn = min(5, len(members))
                spacing = np.median(cKDTree(pos[members]).query(pos[members], k=kn)[0][:, kn - 1])
                near = todo[_reaching_back(pos[todo], behind, spacing)]
        d_band, _ = cKDTree(pos[near]).query(src_pos, distance_upper_bound=cfg.band)
        in_band = np.isfinite(d_band)
        if in_band.sum() < cfg.k:
            in_band = np.ones(len(src), bool)
        band_idx = np.flatnonzero(in_band)  # into src
        band_pos, band_col = src_pos[band_idx], col[src][band_idx]
        # the neckline left out of a torso's band (``neckline_parts``); only with a band of at least
        # 4 k Gaussians (``resolved``): on a coarse model (17 band Gaussians on the whole torso, 7
        # of them near the neck) the neckline is not resolved from the sides
        resolved = 4 * cfg.k
        if never_behind and name in cfg.neckline_parts and len(band_pos) >= resolved:
            neck = parts == PART_INDEX["neck"]
            if neck.any():
                d_neck, _ = cKDTree(pos[neck]).query(band_pos)
                far = d_neck > cfg.neckline_reach
                if far.sum() < resolved:
                    # fewer left past the neckline do not resolve the sides either: the cut coat photo's torso, hidden below
                    # the shoulders by the layer and the folded arms, kept 19 of 452, the white
                    # of the shirt between its lapels, and its upper back came out white
                    neckline_only.append(p)
                    continue  # left to the fallback below: the neighbouring parts' colours
                band_idx, band_pos, band_col = band_idx[far], band_pos[far], band_col[far]
        # colours the garment shows round BOTH sides: a band Gaussian is kept when the band of the
        # other side (left/right of the part's centre) shows its colour at a nearby height; a
        # front-only detail that reaches one side (an off-centre emblem) is dropped from the band.
        # Judged after the neckline is left out: on the red-dress photo the lit blonde strands over
        # one side of the chest matched the open collar's skin on the other, stayed when the skin
        # went, and painted a light blotch on the upper back (283 of its Gaussians)
        both = _on_both_sides(band_pos, band_col, pos[members, 0].mean(), cfg)
        if both.sum() >= cfg.k:
            band_idx, band_pos, band_col = band_idx[both], band_pos[both], band_col[both]
        covered = None
        if posterior:
            behind = band_pos[:, 1] > centre_y
            # the hair read on the front: for a head with fewer than ``k`` band Gaussians behind
            # its centre, and first for one never seen behind it (``behind_share``) however many
            # lie just behind: the sweater photo's head, bent and turned, had 9 there (218 trusted
            # in all, 2 % of the head), its silhouette's edge, and their median painted the back
            # of the head a skin-and-hair brown. Where the hair rule stands down the posterior
            # band stands, when it has ``k`` (the green-jacket photo: face and hair split the
            # middle 38 to 37, and the back of the head keeps the hair of its band)
            if never_behind or behind.sum() < cfg.k:
                centre = np.array([pos[members, i].mean() for i in range(3)])
                # the hair is read on the rim of the seen head: from ``hair_seen`` when given (the
                # flags eroded less; a ring of hair round a face is a strip, as a limb is)
                hsrc = src if hair_seen is None else members[hair_seen[members]]
                if len(hsrc) < cfg.k:
                    hsrc = src
                hair = hair_sources(pos[hsrc], col[hsrc], centre[0], contrast=cfg.hair_contrast,
                                    min_share=cfg.hair_min_share, k=cfg.k, skin=skin)
                if hair.any():
                    covered = hair_covered(pos[todo], pos[hsrc], hair, centre)
            if covered is None and behind.sum() >= cfg.k:
                band_idx, band_pos, band_col = band_idx[behind], band_pos[behind], band_col[behind]
                face = face_coloured(src_pos, col[src], pos[members, 0].mean(), contrast=cfg.hair_contrast,
                                     min_share=cfg.hair_min_share, k=cfg.k, skin=skin)[band_idx]
                if (~face).sum() >= cfg.k:
                    band_pos, band_col = band_pos[~face], band_col[~face]
        # 2. low-frequency fill along the wrap direction (same height). Where the band falls short
        # (a layer's row, a height it does not reach) the seen Gaussians stand in, in colours the
        # part shows on both sides at that height: the green-jacket photo's open front showed the
        # white shirt and collar on one side only, and its top rows carried them onto the back
        fills_by_rows = on_grid and cfg.layer_row_median
        if by_rows and row_seen is not None:  # rows the camera saw as cloth read on the flags before erosion
            src = _cloth_row_sources(members, seen, row_seen, pos, col, centre_y, layer_grid, cfg)
            src_pos = pos[src]
        pool = None
        if fills_by_rows or (cfg.band_reach > 0 and not (posterior or never_behind)):
            pool = _on_both_sides(src_pos, col[src], pos[members, 0].mean(), cfg)
            if pool.sum() < cfg.k:
                pool[:] = True
        if fills_by_rows:
            row_of = lambda i: (i - members[0]) // layer_grid[1]  # noqa: E731
            if by_rows:
                # a row fewer than ``k`` of whose colours the other side shows keeps its own: on
                # the long-skirt photo at 380 px the navy of the layer's top rows was seen on one
                # side only (beside white sleeves on the other); none of it, or one to five white
                # Gaussians at the rows' ends, passed, and those rows' backs took the white
                src_rows = row_of(src)
                pooled = np.bincount(src_rows[pool], minlength=layer_grid[0])
                own = np.bincount(src_rows, minlength=layer_grid[0])
                pool = pool | ((pooled < cfg.k) & (pooled < own))[src_rows]
                rows_s, pos_s, col_s = src_rows[pool], src_pos[pool], col[src][pool]
                low = _row_median(row_of(todo), pos[todo], rows_s, pos_s, col_s, rows_s, pos_s, col_s, len(src))
                low = _row_profile(row_of(todo), low, cfg.layer_profile_rows, cfg.palette_tolerance,
                                   cfg.layer_profile_luminance)
                layer_rows_only[todo] = True
            else:
                low = _row_median(row_of(todo), pos[todo], row_of(src[band_idx]), band_pos, band_col,
                                  row_of(src[pool]), src_pos[pool], col[src][pool], cfg.k)
            rest = ~np.isfinite(low).all(1)  # rows with no seen Gaussian: the slab
            if rest.any():
                low[rest] = _same_height_median(pos[todo][rest], band_pos, band_col, cfg)
        else:
            # heights the band does not reach (``band_reach``): the part's seen Gaussians there
            # (``pool``). Not where the band is narrowed on purpose: the head's posterior band
            # (its ears are not its back), a part never seen behind its centre (a photo: its band
            # is the whole seen edge)
            seen_row = None
            if pool is not None:
                row_pool = pool
                if name in cfg.neckline_parts:
                    # nor the neckline: a back closes higher than a front, and at the heights of
                    # the front's neckline the back is cloth. Left out: the seen surface within
                    # ``band`` of the neck (the collar's edge, blended with the skin above it) and
                    # the skin's colour below it (a V-neck). With the skin alone, tight seed 1 and
                    # wide trousers seed 1 took a light line across the top of their shirts' backs
                    far = np.ones(len(src), bool)
                    neck = parts == PART_INDEX["neck"]
                    if neck.any():
                        far = cKDTree(pos[neck]).query(src_pos)[0] > cfg.band
                    if skin is not None:
                        far &= ~(np.abs(col[src] - skin) <= cfg.palette_tolerance).all(1)
                    if (row_pool & far).sum() >= cfg.k:
                        row_pool = row_pool & far
                seen_row = (src_pos[row_pool], col[src][row_pool])
            low = _same_height_median(pos[todo], band_pos, band_col, cfg, seen_row=seen_row)
        if covered is not None and covered.any():
            if cfg.hair_slab > 0:
                fewest = max(cfg.k, int(np.ceil(cfg.hair_profile_share * hair.sum())))
                low[covered] = height_profile(pos[todo][covered, 2], pos[hsrc][hair][:, 2], col[hsrc][hair],
                                              cfg.hair_slab, fewest)
            else:
                low[covered] = _same_height_median(pos[todo][covered], pos[hsrc][hair], col[hsrc][hair], cfg)
        if name in cfg.face_mirror_parts and cfg.face_mirror_reach > 0:
            # read on the flags before erosion (``row_seen``; else ``hair_seen``): a photo's seen
            # flags on a face are dotted, and the grey-skirt photo's head kept 211 of its 1,664
            # seen Gaussians eroded by 2 texels, 538 by 1
            flags = row_seen if row_seen is not None else hair_seen
            msrc = src if flags is None else members[flags[members]]
            across = _left_right_mirror(pos[todo], pos[msrc], col[msrc], pos[members, 0].mean(), centre_y,
                                        cfg.face_mirror_reach)
            found = np.isfinite(across[:, 0])
            low[found] = across[found]
            mirrored_across[todo[found]] = True
        # 3. the mirrored colour, kept where the band shows that colour at a nearby height
        query = pos[todo].copy()
        middle = centre_y
        if cfg.mirror_column > 0:
            middle = column_middle(pos[members], query, cfg.mirror_column, centre_y)
        query[:, 1] = 2 * middle - query[:, 1]
        dist, idx = cKDTree(src_pos).query(query)
        mirrored = col[src][idx]
        keep = dist <= cfg.max_mirror_distance
        if name in cfg.no_mirror_parts or by_rows:
            keep[:] = False
        if no_mirror is not None:
            keep &= ~no_mirror[todo]
        hair_here = members[over_hair[members]]
        if cfg.hair_over_mirror and len(hair_here) and keep.any():
            d_hair, _ = cKDTree(pos[hair_here]).query(query)
            keep &= d_hair > dist
        if keep.any():
            height = cfg.palette_height
            if on_grid:
                row = _layer_row_spacing(pos[members], layer_grid[0])
                if row is not None:
                    height = cfg.layer_palette_rows * row
            band_tree = cKDTree(_joint(band_col, band_pos[:, 2], cfg, height))
            q = _joint(mirrored, query[:, 2], cfg, height)
            # a band colour within the tolerance in every channel and within ``height`` in height:
            # a box test, the max-norm in the joint (colour, scaled height) space
            dp, _ = band_tree.query(q, p=np.inf)
            keep &= dp <= cfg.palette_tolerance
        out[todo] = np.where(keep[:, None], mirrored, low)
        filled[todo] = True
        if on_grid:
            cont, done = continue_layer(col[members], seen[members], layer_grid[:2], layer_grid[2])
            if no_mirror is not None:  # a redo asks for the low-frequency fill only
                done &= ~no_mirror[members]
            out[members[done]] = cont[done]
            periodic[members[done]] = True
    # a part whose band was all neckline takes the nearest colours of the other parts, not its own
    # seen front (the shirt between an open jacket's lapels); before the fallback below, so that
    # the parts left to it (a neck hidden by a collar) find it filled
    for p in neckline_only:
        own = np.flatnonzero((parts == p) & ~seen)
        other = np.flatnonzero((seen | filled) & (parts != p))
        if len(own) and len(other):
            _, idx = cKDTree(pos[other]).query(pos[own])
            out[own] = out[other[idx]]
            filled[own] = True
    # the front of a photo's neck and of the parts round it, where the images cover it and never
    # show it (``occluded_parts``): what they show where it lies. After the parts above, so that a
    # torso filled from its neighbours does not take the neck's skin
    if occluded is not None and cfg.occluded_parts:
        _from_the_images(out, filled, from_images, pos, parts, ~front_only, surf, occluded, cfg)
    coat_filled = np.zeros(len(pos), bool)  # a torso's back given its coat's colour (``coat_back``)
    coat = coat_colour(col, parts, seen, cfg) if cfg.coat_back else None
    if coat is not None:
        torso = parts == PART_INDEX["torso"]
        back = torso & front_only & visible & (pos[:, 1] > pos[torso, 1].mean())
        back &= (np.abs(out - coat) > cfg.palette_tolerance).any(1)
        out[back] = coat
        filled[back] = coat_filled[back] = True
    rest = np.flatnonzero(~seen & ~filled)
    if len(rest):
        # the nearest seen or already filled Gaussian of any part: the back of a neck a photo's
        # collar and hair hid takes the filled back of the head or the collar behind it, not the
        # jaw's skin in front (a skin-coloured band at the coat photo's nape)
        src = np.flatnonzero(seen | filled)
        _, idx = cKDTree(pos[src]).query(pos[rest])
        out[rest] = out[src[idx]]
    # 4a. parts never seen behind their centre: the per-channel median of the nearest Gaussians of
    # the part (seen ones included), which removes blotches smaller than its reach and keeps the
    # colours and the boundaries of larger regions (a mean would blend hair, skin and cloth). Not
    # on a face's side mirrored from its other (``face_mirror_parts``): that is a reading of the
    # face, an eye or a brow included, not a guess to be evened out (the synthetic one-frame photos
    # gain 0.008-0.040 dB unseen over taking the median there too)
    if cfg.front_only_median > 1 and front_only.any():
        snap = out.copy()
        for p in np.unique(parts[front_only]):
            members = np.flatnonzero(parts == p)
            todo = members[front_only[members] & ~periodic[members] & ~layer_rows_only[members]
                           & ~mirrored_across[members] & ~from_images[members] & ~coat_filled[members]]
            members = members[~over_hair[members] & ~from_images[members]]
            k = min(cfg.front_only_median, len(members))
            if len(todo) == 0 or k < 2:
                continue
            _, nn = cKDTree(pos[members]).query(pos[todo], k=k)
            out[todo] = np.median(snap[members][nn], axis=1)
    # 4b. a few Jacobi sweeps over the UV grid on the unseen Gaussians
    if neighbours is not None and cfg.smooth_sweeps > 0:
        nb = np.asarray(neighbours)
        same = (nb >= 0) & (parts[np.maximum(nb, 0)] == parts[:, None])
        todo = unseen_all[~periodic[unseen_all]]
        for _ in range(cfg.smooth_sweeps):
            s = out.copy()
            acc = s.copy()
            cnt = np.ones(len(s))
            for j in range(nb.shape[1]):
                ok = same[:, j]
                acc[ok] += s[nb[ok, j]]
                cnt[ok] += 1
            sm = acc / cnt[:, None]
            out[todo] = sm[todo]
    if hair_back is not None:  # hair worn down, read in the images (``long_hair_colors``)
        got = np.isfinite(hair_back).all(1) & ~seen & visible
        out[got] = hair_back[got]
    if ul is not None:
        hide = (ul >= 0) & ~seen
        out[hide] = out[ul[hide]]
    if cut_colors is not None and cfg.cut_fill:
        out = apply_cut_colors(out, parts, seen, _per_gaussian(cut_colors, len(pos), "cut_colors"), under_layer=ul)
    return torch.as_tensor(np.clip(out, 0.0, 1.0), dtype=torch.float32)
