"""Stage I's seen flags recounted on the person at the end of the stage, before the unseen fill.

Paper Eq. 7 marks a Gaussian seen when it is the first hit of a training ray. During training the
flags accumulate over every step, and a first hit counts wherever the avatar has coverage, also
on pixels the frame's mask calls background: Gaussians that stick out past the silhouette (most
at the sides of the head, seen only at grazing incidence) are marked seen although no pixel of the
person ever showed them. Their colour is not the person's: with a fixed black background they
learn black (the dark rims), with a random one its mean grey. As seen Gaussians they are colour
sources of the unseen fill, and the back of the head took their grey (seed 2 of the garment
benchmark, 10-minute budget: 1,931 such Gaussians, 1,373 on the head; the face-region
front_leak 0.196).

So at the end of Stage I the final avatar is rendered from every training frame once, and a seen
Gaussian stays seen only if it is the first hit (facing the camera, as in ``mark_seen``) of at
least one pixel the mask gives to the person (mask > ``PERSON``). The others become unseen and are
repainted by the fill like the rest of the unseen side. Training itself never reads the flags, so
Stage I's steps are unchanged; painted visibility (edits) still overrides the result.

First hits alone miss much of what the images fitted. A pixel is the blend of every Gaussian along
its ray up to saturation, and only one of them is its first hit: with few training views (one
photo) many of the Gaussians that draw the person are never a first hit, the fill repainted them
as unseen, and the training view itself changed (a coat photo, 450 steps: 5,109 such Gaussians
draw at least a quarter pixel of it; the photo's PSNR inside the mask fell 25.9 -> 20.6 dB after
the fill). With ``min_weight`` the recount also marks seen every Gaussian that blends at least
``min_weight`` pixels' worth of weight into the person's pixels of ONE training frame, with at
least ``MIN_PERSON_SHARE`` of all its weight (over the frames) on the person, not off the
silhouette, in a frame that sees its surface from outside (a garment layer's, below). One frame,
not the sum over frames, and only the person's pixels ``INSET`` px or more inside the silhouette:
in a 60-frame video, 6,378 Gaussians that are no first hit blend 1.3 px over the frames (median)
but 0.05 px in their best frame, nearly all at grazing incidence at the silhouette; their colours
are fitted to the edge's blend, the fill's are better, and keeping them cost the tight benchmark
2 dB unseen (seed 0: 29.25 -> 27.26 dB with a 0.05 px sum over the frames). Nor does the body's own normal tell them apart: on the coat photo a quarter
of the Gaussians that draw its inside do not face the camera by it (the body's sides, pulled out
to the coat's), and a facing test on it kept the photo at 22.6 dB.

The Gaussians seen by their weight alone keep their colour through the fill but are no colour
source of it (``SeenRecount.blended_only``): many sit at the silhouette at grazing incidence, where
a photo's matting leaves a light fringe, and as sources they streaked the back of that coat with
white. On a garment layer, a frame counts for a Gaussian only where it sees the layer's surface
from outside (the posed layer normal, not the learned one, faces the camera): through a coat's
front opening the camera sees the inside of the layer's back panel, whose trained colours are the
inside's. The body is a closed surface and gets no such test: a body Gaussian whose normal turns
from the camera and still blends into the person lies behind semi-transparent ones at the
silhouette's edge (the side of a neck behind loose hair), and with the test the fill repainted it
in the training view too (the grey-skirt photo, 500 steps: 22.64 dB inside the mask after the
finish with the test, 22.92 without it; `docs/loose_clothing.md`, "A photo's own view after the
finish"). There is no facing test on the learned normals: without normal maps to fit, many of them
turn away from the camera (the coat photo: 41 % of the Gaussians that draw it).

One more test is on the body's surface normal, posed, and on the whole clip: a body Gaussian whose
surface faces away from the camera by more than 120 degrees (cosine below ``BODY_AWAY_COS``) in
every training frame is not seen, whatever it blends in or is the first hit of. It lies on the
back, and what the images gave it is what lies in front at the silhouette: on a coat photo whose
camera looked down over the shoulders, 178 torso Gaussians of the upper back kept the colours of
the hair and the collar lying over the shoulders, and the back came out in blotches. Sides and a
neck behind loose hair turn less than that from the camera and keep their colours.

The weights are the gradient of the image with respect to a zero colour probe:
d(sum of pixels)/d(colour) is the sum of alpha times transmittance over the pixels a Gaussian
touches.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, NamedTuple

import torch

from ..avatar.state import facing_hits
from .render import render_avatar

if TYPE_CHECKING:
    from ..avatar.state import AvatarState
    from .data import TrainingData

PERSON = 0.5  # a pixel belongs to the person where its mask exceeds this
# a body Gaussian whose posed surface normal makes a cosine below this with the direction to the
# camera in every training frame (it faces away by more than 120 degrees) is not seen, first hit or not
BODY_AWAY_COS = -0.5
MIN_PERSON_SHARE = 0.5  # of a Gaussian's blend weight that must land on the person for it to count
INSET = 2  # px: a frame's weight for the rule counts on the person's pixels this far inside the silhouette


@dataclasses.dataclass
class PersonCoverage:
    """What the training frames show of each Gaussian, on the person's pixels."""
    first_hits: torch.Tensor  # (N,) int64: person pixels it is the facing first hit of
    weight: torch.Tensor | None = None  # (N,) float64: blend weight on person pixels, summed over the frames
    total: torch.Tensor | None = None  # (N,) float64: blend weight on every pixel, summed over the frames
    weight_max: torch.Tensor | None = None  # (N,) float64: the largest one frame's blend weight on the
    # person's pixels at least INSET px inside the silhouette, in frames that see its surface from outside
    # (a garment layer's; the body's count in every frame)
    total_max: torch.Tensor | None = None  # (N,) float64: the largest one frame's blend weight on every pixel,
    # in frames that see its surface from outside (every frame for the body's Gaussians)
    faces_away: torch.Tensor | None = None  # (N,) bool: body Gaussians whose surface faces away from the
    # camera in every frame (cosine below BODY_AWAY_COS); None: not computed (no test applies)


class SeenRecount(NamedTuple):
    dropped: int  # seen, but the first hit of no person pixel: now unseen
    added: int  # not seen, but blended into the person's pixels: now seen
    blended_only: torch.Tensor  # (N,) bool: seen now by the blend weights alone (no first hit on the person)


def person_coverage(state: AvatarState, data: TrainingData, *, hit_threshold: float = 0.5,
                    weights: bool = False) -> PersonCoverage:
    """Render the avatar as it is now (pose corrections included) from every training frame once:
    the facing first hits on person pixels and, with ``weights``, the blend weights."""
    n = state.num_gaussians
    counts = torch.zeros(n, dtype=torch.long)
    zeros = (lambda: torch.zeros(n, dtype=torch.float64)) if weights else (lambda: None)
    weight, total, weight_max, total_max = zeros(), zeros(), zeros(), zeros()
    nb = state.model.num_body  # the body's Gaussians come first, a garment layer's after them
    layer = weights and n > nb
    best_cos = torch.full((nb,), -2.0, dtype=torch.float64)  # the body's, facing the cameras
    for i in data.frames:
        tgt = data.targets[i]
        with torch.no_grad():
            posed, surface_normals = state.posed_with_surface_normals(i)
            # every Gaussian's surface against the direction to the camera: the body's test below
            # (facing away in every frame) and a garment layer's (seen from outside in this one)
            centre = torch.as_tensor(tgt.camera.center, dtype=posed.means.dtype, device=posed.means.device)
            to_cam = centre - posed.means
            cos = ((to_cam * surface_normals).sum(1) / to_cam.norm(dim=1).clamp_min(1e-9)).cpu().double()
            torch.maximum(best_cos, cos[:nb], out=best_cos)
        person = tgt.mask > PERSON
        if weights:  # colours as a leaf: red carries the person-masked sum, green the whole image's,
            # blue the sum inside the silhouette's band
            probe = torch.zeros_like(posed.colors).requires_grad_(True)
            r = render_avatar(dataclasses.replace(posed, colors=probe), tgt.camera, data.background, normals=False,
                              first_hit=True, hit_threshold=hit_threshold)
            m = person.to(r.rgb.device, r.rgb.dtype)
            inner = tgt.inner_mask(INSET).to(r.rgb.device, r.rgb.dtype)
            ((r.rgb[..., 0] * m).sum() + r.rgb[..., 1].sum() + (r.rgb[..., 2] * inner).sum()).backward()
            g = probe.grad.detach().cpu().double()
            weight += g[:, 0]
            total += g[:, 1]
            outside = torch.ones(n, dtype=torch.bool)
            if layer:  # a layer Gaussian counts where its surface is not seen from within
                outside[nb:] = cos[nb:] >= 0
            torch.maximum(weight_max, g[:, 2] * outside, out=weight_max)
            torch.maximum(total_max, g[:, 1] * outside, out=total_max)
        else:
            with torch.no_grad():
                r = render_avatar(posed, tgt.camera, data.background, normals=False, first_hit=True,
                                  hit_threshold=hit_threshold)
        hit = r.first_hit.detach()
        hits = facing_hits(hit[person.to(hit.device) & (hit >= 0)], posed, tgt.camera)
        counts += torch.bincount(hits.cpu(), minlength=n)
    faces_away = torch.zeros(n, dtype=torch.bool)
    faces_away[:nb] = best_cos < BODY_AWAY_COS
    return PersonCoverage(counts, weight, total, weight_max, total_max, faces_away)


def person_first_hits(state: AvatarState, data: TrainingData, *, hit_threshold: float = 0.5) -> torch.Tensor:
    """(N,) how many pixels of the person, over the training frames, each Gaussian is the first hit
    of while facing the camera (the avatar as it is now, pose corrections included)."""
    return person_coverage(state, data, hit_threshold=hit_threshold).first_hits


def blended_on_person(coverage: PersonCoverage, min_weight: float, *, min_share: float = MIN_PERSON_SHARE) -> torch.Tensor:
    """(N,) bool: blend weight on the person of at least ``min_weight`` pixels in one frame, and at
    least ``min_share`` of the Gaussian's whole weight (over the frames) on the person."""
    if coverage.weight is None:
        raise ValueError("blended_on_person: the coverage was computed without weights")
    return (coverage.weight_max >= min_weight) & (coverage.weight >= min_share * coverage.total)


def untrained_colours(model) -> torch.Tensor | None:
    """(N,) bool: the Gaussians whose colour no training step touched -- their per-Gaussian colour
    residual is still exactly its initial zero (any colour gradient moves it: Adam's first step is
    about the learning rate) -- so that their colour is the decoder's guess for their texel. None
    for a model without the residual (``AvatarConfig.color_residual`` off: nothing tells)."""
    residual = getattr(model.decoder, "color_residual", None)
    if residual is None:
        return None
    return (residual.detach() == 0).all(1).cpu()


def unsee_untrained(state: AvatarState) -> int:
    """Unmark the seen Gaussians whose colour training never touched (``untrained_colours``): the
    final avatar's blend weights can mark a Gaussian seen that no step of training coloured (on a
    photo's back, facing the camera by 118 degrees, behind the front it blends through), and as seen
    it kept the decoder's grey-mauve guess, and its ring with it. Call it before the fill, which sets
    the residuals it fills. Returns how many were unmarked."""
    untrained = untrained_colours(state.model)
    if untrained is None:
        return 0
    drop = state.seen & untrained.to(state.seen.device)
    state.seen &= ~drop
    return int(drop.sum())


def keep_seen_on_person(state: AvatarState, data: TrainingData, *, hit_threshold: float = 0.5,
                        min_weight: float | None = None, coverage: PersonCoverage | None = None) -> SeenRecount:
    """Unmark the seen Gaussians that are the first hit of no person pixel in any training frame;
    with ``min_weight``, mark seen those ``blended_on_person``. Returns how many were unmarked and
    how many marked. ``coverage``: ``person_coverage`` of the avatar as it is, if already computed."""
    cov = coverage or person_coverage(state, data, hit_threshold=hit_threshold, weights=min_weight is not None)
    on_person = cov.first_hits > 0
    if min_weight is not None:
        on_person |= blended_on_person(cov, min_weight)
    if cov.faces_away is not None:
        on_person &= ~cov.faces_away.to(on_person.device)
    drop = state.seen & ~on_person
    add = on_person & ~state.seen if min_weight is not None else torch.zeros_like(on_person)
    state.seen &= on_person
    state.seen |= add
    return SeenRecount(int(drop.sum()), int(add.sum()), on_person & ~(cov.first_hits > 0))
