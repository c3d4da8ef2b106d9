"""The hair of a head seen only from the front: which seen Gaussians of the head show it, and which
unseen ones it covers. Used by the wrap-around fill (``wrap_fill``) when the head has too few
seen Gaussians behind its centre for the posterior band (one photo, or a video that never turned),
and, for the face's colour alone, to keep skin out of that band when it has enough.

Why. From the front the head is a face framed by hair (or a hat): hair at the top and the sides,
skin in the middle. The fill carries the seen colours round at the same height, so at face height
it carried the face -- a bald, skin-coloured back of the head, with the lips' red wrapped round it
as a band (measured on photos of a woman with a beret and long dark hair, and of a woman with
tied-back blonde hair).

The rule, in canonical space (the body faces -Y, +Z up), on the head's seen Gaussians:

1. **Face and hair colours**: two colour clusters of the seen head (a few Lloyd iterations),
   started from the median colour of the middle of the seen head (the ``CENTRE`` share nearest
   to the head's midline in x, between the ``CENTRE`` and ``1 - CENTRE`` quantiles of height:
   cheeks, nose, eyes) and from the rim colours farthest from it. The face's cluster is the one
   that holds more of the middle; glasses and lips are too few to make a cluster of their own.
   Only Gaussians inside a region of their cluster's colour vote (``CORE_AGREE`` of their
   ``CORE_K`` nearest seen ones in it): thin dark features (glasses' frames, brows, eyes) do not,
   broad hair across the face does; a middle with fewer than ``k`` of them votes whole.
2. **The hair**: the seen Gaussians on the rim of the seen head (the outer ``1 - RIM`` share in
   |x| or in height) in the other cluster. When the two clusters' colours differ by no more than
   ``contrast`` in every RGB channel, or fewer than ``min_share`` of the seen head (or fewer than
   ``k``) are hair, the head shows no hair of its own colour (bald, or hair as light as the skin):
   the rule stands down and the fill is as before. It stands down too when the face's cluster
   holds less than ``FACE_SHARE`` of the middle: a middle split between two colours (hair falling
   across the face, a head bent forward) tells no face from hair (on a photo of a laughing woman
   with long red-blonde hair over her cheeks, the dark cluster -- mouth and shadowed hair -- won
   the middle with 58 % and the back of her head would have turned skin-coloured).
3. **What the hair covers**: the unseen Gaussians of the head behind its centre (y above the
   centre's), and those above the top of the face or beside it (the ``FACE_TOP`` quantiles of
   height and of |x| of the seen Gaussians that are not hair): the back of the head, the crown
   and the temples. Unseen Gaussians among the face's own (a photo's seen flags are dotted) keep
   the fill's colours of their height.

Each such Gaussian takes the median colour of the nearest hair Gaussians at its height (the
fill's same-height median), so a hat over hair keeps the hat above and the hair below.

**The skin of the hands decides which cluster is the face** (``skin``, from ``skin_reference``).
The middle of a photo's seen head is not always the face: a laughing woman with her head bent
forward showed the crown and the hair over her cheeks, and the flags left the face dotted. The
middle's core voted 20 to 4 for the dark cluster (shadowed strands, the open mouth), and the pale
cluster -- her skin with the golden strands -- was taken for hair: the back of her head came out
skin-coloured. The same person's hands show her skin. When the seen hands give a warm colour (R >=
G >= B, R - B >= ``SKIN_WARMTH``: a gloved hand in black, grey or green does not), and one cluster's
colour is nearer to it than ``SKIN_RATIO`` times the other's, that cluster is the face, provided it
holds at least ``SKIN_MIN_MIDDLE`` of the middle (every Gaussian voting); then the middle's share
test is not asked. Otherwise the vote decides, as above.

**A head the video saw behind its centre** (the posterior band of the fill) uses step 1 only
(``face_coloured``): the band's Gaussians in the face's colour cluster -- the ears and the skin
behind the jaw, which a turning video sees just behind the coronal plane -- are left out of the
band, so that the back at ear and nape height takes the hair above and below it.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

# quantiles of the seen head that delimit its middle (the face) and its rim (hair, hat)
CENTRE = 0.3
RIM = 0.7
# quantile of the face's seen Gaussians' height (and |x|) taken as the top (and the side) of the face
FACE_TOP = 0.95
# share of the middle the face's cluster must hold (less: hair across the face, a head bent down)
FACE_SHARE = 0.75
LLOYD_STEPS = 10  # iterations of the two-cluster split
# the middle's vote counts only Gaussians inside a region of their cluster's colour: at least
# CORE_AGREE of their CORE_K nearest seen ones (~7 mm on a photo's head, 3.4 mm spacing) in it.
# Thin dark features on a face (glasses' frames, brows, eyes) do not vote; broad hair across it
# does. The coat photo (big black-rimmed glasses, a beanie): the face's cluster held 68 % of the
# middle and the rule stood down (a skin-coloured back of the head); of the core, 100 %. The four
# other photos keep their decision (core shares 0.71-0.97, all-Gaussian shares 0.60-0.80)
CORE_K = 16
CORE_AGREE = 0.85
# the hands' skin as the face's reference (module docstring): the reference must be warm (R >= G >=
# B, R - B at least SKIN_WARMTH), one cluster nearer to it than SKIN_RATIO times the other, and
# that cluster at least SKIN_MIN_MIDDLE of the middle's Gaussians. The red-dress photo: distances
# 0.13 (pale cluster) and 0.67 (dark), the pale cluster 35 % of the middle
SKIN_WARMTH = 0.05
SKIN_RATIO = 0.5
SKIN_MIN_MIDDLE = 0.25
# seen hand Gaussians needed for a reference
SKIN_MIN_COUNT = 32


def skin_reference(hand_colours: np.ndarray) -> np.ndarray | None:
    """(3,) median colour of a person's seen hand Gaussians ``hand_colours`` (H,3), or None when
    there are fewer than ``SKIN_MIN_COUNT`` or the median is not warm (a glove)."""
    if len(hand_colours) < SKIN_MIN_COUNT:
        return None
    ref = np.median(np.asarray(hand_colours, np.float64), axis=0)
    return ref if is_warm(ref) else None


def is_warm(colour: np.ndarray) -> bool:
    """A skin-like colour (3,): R >= G >= B and R - B at least ``SKIN_WARMTH`` (a glove in black,
    grey or green is not)."""
    r, g, b = colour
    return bool(r >= g >= b and r - b >= SKIN_WARMTH)


def _core(src_pos: np.ndarray, label: np.ndarray) -> np.ndarray:
    """(S,) bool: the seen Gaussians at least ``CORE_AGREE`` of whose ``CORE_K`` nearest (itself
    included) share their cluster -- inside a region of their colour, not on a thin feature."""
    k = min(CORE_K, len(src_pos))
    if k < 2:
        return np.ones(len(src_pos), bool)
    _, nn = cKDTree(src_pos).query(src_pos, k=k)
    return (label[nn] == label[:, None]).mean(1) >= CORE_AGREE


def hair_and_face(src_pos: np.ndarray, src_col: np.ndarray, centre_x: float, *, contrast: float,
           min_share: float, k: int, skin: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray] | None:
    """(hair, face) bool masks over the head's seen Gaussians (steps 1-2 of the module
    docstring; ``skin``: the hands' colour from ``skin_reference``, or None); None when the rule
    stands down."""
    n = len(src_pos)
    if n < k:
        return None
    ax = np.abs(src_pos[:, 0] - centre_x)
    z = src_pos[:, 2]
    z_lo, z_hi = np.quantile(z, [CENTRE, 1 - CENTRE])
    middle = (ax <= np.quantile(ax, CENTRE)) & (z >= z_lo) & (z <= z_hi)
    if not middle.any():
        return None
    rim = (ax >= np.quantile(ax, RIM)) | (z >= np.quantile(z, RIM))
    face = np.median(src_col[middle], axis=0)
    far = np.abs(src_col - face).max(axis=1)
    rim_far = rim & (far >= np.median(far[rim]))
    centres = np.stack([face, np.median(src_col[rim_far], axis=0)])
    for _ in range(LLOYD_STEPS):
        label = np.linalg.norm(src_col[:, None] - centres[None], axis=2).argmin(1)
        centres = np.stack([src_col[label == j].mean(0) if (label == j).any() else centres[j] for j in (0, 1)])
    if np.abs(centres[0] - centres[1]).max() <= contrast:
        return None
    face_label = _face_by_skin(centres, skin, label[middle])
    if face_label is None:  # the hands do not tell: the middle's vote, if it is clear
        votes = np.bincount(label[middle & _core(src_pos, label)], minlength=2)
        if votes.sum() < k:  # mixed finely all over the middle: every Gaussian votes
            votes = np.bincount(label[middle], minlength=2)
        face_label = int(votes.argmax())
        if votes[face_label] < FACE_SHARE * votes.sum():
            return None
    hair = rim & (label != face_label)
    if hair.sum() < max(k, min_share * n):
        return None
    return hair, label == face_label


def _face_by_skin(centres: np.ndarray, skin: np.ndarray | None, middle_label: np.ndarray) -> int | None:
    """The cluster the hands' skin says is the face (module docstring), or None when it does not
    tell: no reference, no clear nearest cluster, or that cluster too rare in the middle."""
    if skin is None or not len(middle_label):
        return None
    d = np.linalg.norm(centres - skin[None], axis=1)
    near = int(d.argmin())
    if d[near] > SKIN_RATIO * d[1 - near] or (middle_label == near).mean() < SKIN_MIN_MIDDLE:
        return None
    return near


def hair_sources(src_pos: np.ndarray, src_col: np.ndarray, centre_x: float, *, contrast: float,
                 min_share: float, k: int, skin: np.ndarray | None = None) -> np.ndarray:
    """(S,) bool over the head's seen Gaussians (canonical positions ``src_pos``, colours
    ``src_col``): those that show hair (rim, not face-coloured). All False when too few do.
    ``skin``: the hands' colour (``skin_reference``), or None."""
    split = hair_and_face(src_pos, src_col, centre_x, contrast=contrast, min_share=min_share, k=k, skin=skin)
    return np.zeros(len(src_pos), bool) if split is None else split[0]


def face_coloured(src_pos: np.ndarray, src_col: np.ndarray, centre_x: float, *, contrast: float,
                  min_share: float, k: int, skin: np.ndarray | None = None) -> np.ndarray:
    """(S,) bool over the head's seen Gaussians: those in the face's colour cluster (skin: the
    face, the ears, a bare neck), when the head shows hair of its own colour; all False when the
    rule stands down (a bald head, hair as light as the skin). ``skin``: as ``hair_sources``."""
    split = hair_and_face(src_pos, src_col, centre_x, contrast=contrast, min_share=min_share, k=k, skin=skin)
    return np.zeros(len(src_pos), bool) if split is None else split[1]


def hair_covered(todo_pos: np.ndarray, src_pos: np.ndarray, hair: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """(T,) bool over the head's unseen Gaussians: those the hair covers -- behind the head's
    ``centre``, above the top of the face or beside it (the seen Gaussians that are not hair)."""
    face = src_pos[~hair]
    if not len(face):
        return todo_pos[:, 1] > centre[1]
    top = np.quantile(face[:, 2], FACE_TOP)
    half_width = np.quantile(np.abs(face[:, 0] - centre[0]), FACE_TOP)
    return (todo_pos[:, 1] > centre[1]) | (todo_pos[:, 2] > top) | (np.abs(todo_pos[:, 0] - centre[0]) > half_width)
