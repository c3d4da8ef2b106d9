"""Training configuration with the paper's defaults (Appendix A.1) and this machine's sizes.

``StageSettings`` is what every stage has -- its length (steps or minutes, whichever ends first)
and its learning-rate decay -- so Stage I and Stage II share one definition of both."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

from .. import config as config_layer
from ..avatar.config import AvatarConfig
from ..schedule import Scheduled


@dataclass
class StageSettings:
    # length: whichever comes first
    iters: int = 6000
    minutes: float | None = None
    # learning rates x lr_gamma at each of these fractions of the stage
    lr_milestones: tuple[float, ...] = (1 / 3, 2 / 3)
    lr_gamma: float = 0.1

    label: ClassVar[str] = ""  # prefix of error messages ("Stage II ")

    def __post_init__(self) -> None:
        if self.iters < 1:
            raise ValueError(f"{self.label}--iters must be at least 1, found {self.iters}")
        if self.minutes is not None and self.minutes <= 0:
            raise ValueError(f"{self.label}--minutes must be positive, found {self.minutes}")

    def progress(self, steps: int, seconds: float) -> float:
        """Fraction of the stage done: whichever of its steps or minutes ends first."""
        p = steps / self.iters
        if self.minutes:
            p = max(p, seconds / (60.0 * self.minutes))
        return min(p, 1.0)

    def lr_schedule(self) -> Scheduled:
        """The learning-rate multiplier over the stage's fraction done."""
        return Scheduled.drops(1.0, at=self.lr_milestones, factor=self.lr_gamma)

    def to_dict(self) -> dict:
        return config_layer.to_dict(self)

    @classmethod
    def from_dict(cls, d: dict):
        return config_layer.from_dict(cls, d, cls.label + "training")


# what a run recorded before each avatar setting existed trained with (``Stage1Config.from_dict``)
AVATAR_BEFORE_SETTING = {
    "color_residual_gain": 1.0,  # before the gain existed
    "garment_skin_sectors": 1,  # before the sectors existed
    "decoder_init": "torch",  # before the decoder's He init
    "garment_clearance": 0.0,  # before the layer kept clear of the body
    "garment_stretch_scales": False,  # before discs followed the pose's stretch
    "garment_layer_step": 0.02,  # before the rows' spacing was a setting
    "garment_decode_every": 1,  # before the layer's nodes existed
    "garment_filter_one_tube": 1.0,  # before a one-tube layer's filter had its own width
    "garment_layer": "off",  # before the garment layer existed
}


@dataclass
class Stage1Config(StageSettings):
    # loss weights (paper Appendix A.1.3)
    lambda_rgb: float = 0.8
    lambda_normal: float = 0.8
    lambda_ssim: float = 0.2
    lambda_lpips: float = 0.2
    lambda_offset: float = 0.85
    lambda_scale: float = 0.03
    lambda_features: float = 1.0
    # frames without a normal map (a user's photo or video): mean (1 - cos) between each decoded
    # Gaussian's normal and its body texel's (or the garment layer's) normal, in place of the normal
    # loss. Without it nothing holds a disc's orientation: fitted to one front view, discs at the
    # silhouette turned to face the camera (long-skirt photo: layer normals 54 deg off at the 90th
    # percentile, the hem's flipped), and from the side they showed edge-on as spikes and smears
    lambda_normal_prior: float = 0.1
    # only with a garment layer (avatar.garment_layer; tight runs are unchanged): rendered alpha
    # against the frame's mask (mean square over the crop), so the layer's opacity fades where the
    # silhouette shows nothing; and the layer's sheet regulariser (mean squared relative change of
    # its grid neighbours' canonical distances, garment_layer.neighbour_strain)
    lambda_alpha: float = 1.0
    lambda_layer_spacing: float = 1.0
    # cloth is opaque: mean (1 - opacity) over the layer's Gaussians. Without it the layer in front
    # of a leg could stay half transparent (the leg behind it learning the cloth's colour), which
    # shows as translucent cloth and as cloth painted on the legs once they move; the alpha loss
    # still fades the layer where the silhouette shows nothing
    lambda_layer_opaque: float = 0.0
    # cloth is opaque where the silhouette says there is something: mean (1 - opacity) over the
    # layer Gaussians of each given view that project layer_cover_inset pixels inside its mask
    # (train/layer_cover.py); those beyond the silhouette are left to the alpha loss. 0.03: trousers
    # seed 1 holes x2 1.35 / 1.18 -> 0.05 / 0.07 % (0.1: 0.01 / 0.05 %, but -1.0 dB seen)
    lambda_layer_cover: float = 0.03
    layer_cover_inset: int = 2
    # the garment layer's learned skinning (AvatarModel.layer_skin_weights: log-factors per tube and
    # bone at knots down the layer): its Adam rate (0 = keep the built weights) and the weight of its
    # prior (AvatarModel.layer_skinning_prior: near the built weights, smooth down the cloth). Stage I only
    lr_layer_skinning: float = 0.01
    lambda_layer_skinning: float = 1e-3
    # learning-rate decay over the budget (steps or minutes, whichever ends first): constant until
    # lr_decay_start of the stage, then geometric down to lr_final x at its end. GaussianAvatar's
    # x lr_gamma drops at 1/3 and 2/3 (``lr_milestones``; used instead when set, as in ``paper()``)
    # froze short runs: a 3-minute run spent two thirds of its steps at 1/10 and 1/100 of its rate.
    lr_milestones: tuple[float, ...] = ()
    lr_decay_start: float = 0.5
    lr_final: float = 0.1
    # optimiser (GaussianAvatar: Adam, decoder 3e-3, feature map 5e-4)
    lr_decoder: float = 3e-3
    lr_features: float = 5e-4
    # per-frame pose refinement (paper: on for in-the-wild videos, off where poses are accurate).
    # ``pose_refinement`` turns it on for any scene; ``pose_refinement_prepared`` for the scenes
    # ``prepare`` made from a video or a folder of frames (their poses are a fit; a photo has one
    # frame, nothing to refine against), not for scenes with exact poses (docs/prepare.md)
    pose_refinement: bool = False
    pose_refinement_prepared: bool = True
    # each frame's correction its own Adam (train/row_adam.py); 5e-3 drew a skin patch on a real
    # video's back, 1e-3 does not (docs/prepare.md, "Pose refinement")
    lr_pose: float = 1e-3
    pose_refinement_start: float = 0.1  # fraction of the run before poses are optimised
    # the corrections' mean over the trained frames held at zero (train/row_adam.py): they correct
    # how the frames differ, the avatar keeps what they share
    pose_refinement_centre: bool = True
    # at the end of the stage, the Gaussians no training view saw take the wrap-around fill's colour
    # of the seen surface (train/unseen_fill.py) instead of the decoder's guess for untrained
    # texels; those within fill_unseen_ring texels of a seen one keep their decoded colour
    fill_unseen: bool = True
    fill_unseen_ring: int = 1
    # before the fill, a seen Gaussian stays seen only if the final avatar shows it on a pixel of
    # the person in some training frame (train/seen_recount.py): Gaussians seen only off the
    # silhouette are no colour source and are filled
    seen_on_person: bool = True
    # ... and a Gaussian that blends at least this many pixels' worth of weight into the person's
    # pixels of one training frame (most of its weight on the person) is seen too, first hit or
    # not: that frame fitted it, and the fill would change it (train/seen_recount.py; None: first
    # hits only)
    seen_min_weight: float | None = 0.25
    # ... and the garment layer's Gaussians that stand on the background in some training frame
    # (more than 2 px off the mask: empty air, whichever way they face) keep their learned opacity
    # instead of the row's (train/unseen_fill.py, layer_off_person)
    layer_off_person: bool = True
    # ... and those of them training made transparent (opacity under 0.5, not trimmed) are the
    # layer's side the person's outline cut away: the body under them takes the cloth's colour
    # (avatar/layer_cover.py, ``AvatarModel.layer_outline_cut``)
    layer_outline_cut: bool = True
    # ... and the seen layer Gaussians under the layer's hem whose colour is the body's seen just
    # under it (the legs under a skirt, trousers under a coat: avatar/layer_through.py) are no
    # colour source for the layer's unseen side
    layer_through: bool = True
    # ... and the seen layer Gaussians that lie behind an arm or a hand in a training frame and took
    # its colour (a loose sleeve wider than the fitted arm, the photo's hand a little off the fitted
    # one) are unseen: the fill gives them the cloth's colour. As the arm's colour they showed on
    # the garment's side as light patches (avatar/layer_through.py, "Behind an arm")
    layer_behind_limbs: bool = True
    # ... and the seen arm and hand Gaussians that lie by the layer in a training frame and took the
    # cloth's colour (a fitted hand larger than the photo's, or off it, on a skirt) are no colour
    # source for the limb's unseen side: the palms and backs of the hands took the cloth's grey
    # (avatar/limbs_over_cloth.py)
    limbs_over_cloth: bool = True
    # ... and the layer Gaussians that the arms and hands hid in every training frame (the rays
    # reach them with the arms transparent, keep less than a quarter of that weight with them: the
    # skirt behind a photo's hand) are unseen, filled and given the row's opacity like the cloth
    # around them. Their trained colours mixed with the hand in front, and showed as a hand-shaped
    # imprint on the cloth once the arm moved (train/hidden_by_limbs.py)
    layer_hidden_by_limbs: bool = True
    # ... those hidden Gaussians with trusted cloth within this many grid steps both ways along
    # their row or their column take the colours read along it, which carry pleats and stripes
    # through the gap, instead of their row's, a flat patch (appearance/gap_fill.py; 0: the row's)
    layer_gap_reach: int = 16
    # ... and the body's Gaussians (not the arms') that the arms and hands hid in every training frame
    # (the chest behind folded arms, the hip behind a hand) are unseen and filled: their trained
    # colours showed as a band of specks across the chest once the arms moved (train/hidden_by_limbs.py)
    body_hidden_by_limbs: bool = True
    # at these fractions of the stage, the seen layer Gaussians under the hem whose colour is the
    # body's just under it (the hem rule of layer_through: the layer reached past the garment's
    # hem and drew the legs) are trimmed off the layer, opacity 0 for good, and the rest of the
    # stage trains the legs behind them. Left in, they hung a band of the legs' colour from the hem
    # once the legs moved (train/hem_trim.py). (): never
    layer_hem_trims: tuple[float, ...] = (0.4, 0.7)
    # ... and the seen layer Gaussians whose surface faced no training camera in any frame were
    # seen from inside the garment (through a coat's open front, the inside of its back): their one
    # colour is the lining's, and from behind it showed on the outside as a dark patch (coat seed
    # 1: +0.47 dB unseen after Stage I). They are unseen, and the fill gives them the cloth's
    # outer colours (train/unseen_fill.py, layer_seen_inside)
    layer_seen_inside: bool = True
    # ... and a seen Gaussian whose colour training never touched (its colour residual is still
    # exactly its initial zero: no step gave it a colour gradient) is unseen: its colour is the
    # decoder's guess for an untrained texel, a grey-mauve. Training culls Gaussians facing away
    # from the camera (``cull_backfacing``), and the recount renders them all: on a photo's upper
    # back, facing away by 118-120 degrees, some blend through the front into the person's pixels,
    # were "seen" by their weight, and kept that colour (with their unseen ring) as blotches
    # (train/seen_recount.py, untrained_colours). (The fill's ring -- unseen Gaussians next to a
    # seen one, which keep their decoded colour -- is left as it is: filling its untouched ones
    # changed the photos' own views at the silhouette's edge, -0.42 dB on one)
    seen_trained_only: bool = True
    # at the end of Stage I the garment layer's front and back move inward in depth by the amount
    # training pulled its sides in more (a splat is drawn past its centre, and the front view's
    # outline pulled the sides in; the front and back kept their built depth and stood some 6 mm
    # too deep in profile: avatar/layer_depth.py)
    layer_depth_match: bool = True
    # images
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # each given-view step composites its target on a uniformly random colour and renders over the
    # same colour (``background`` is then only the evaluation's): with one fixed black background,
    # the Gaussians at the silhouette learn the anti-aliased edge's blend with black as their own
    # colour and show as dark rims from the side and in the unseen fill
    random_background: bool = True
    crop_margin: int = 16  # render and compare only the body's box (plus margin) of each frame
    # decode, pose and render only the Gaussians whose body normal does not point away from the
    # frame's camera by more than this cosine past grazing (None: all, as the paper)
    cull_backfacing: float | None = 0.25
    # LPIPS (only when the user supplies weights)
    lpips_net: str = "alex"
    lpips_backbone: str | None = None
    lpips_lin: str | None = None
    # visibility (paper Eq. 7): a Gaussian is seen when it is the first hit with alpha >= this
    hit_threshold: float = 0.5
    # seen-view validation: every holdout-th frame is kept out of training and compared with the
    # avatar (None: 8 for a scene without evaluation views, e.g. one's own video, else 0; 0 = off)
    holdout: int | None = None
    # bookkeeping
    eval_every_seconds: float = 60.0
    checkpoint_every_seconds: float = 120.0
    seed: int = 0
    threads: int | None = None
    device: str = "cpu"
    avatar: AvatarConfig = field(default_factory=AvatarConfig)

    label: ClassVar[str] = ""

    def __post_init__(self) -> None:
        if isinstance(self.avatar, dict):
            self.avatar = config_layer.from_dict(AvatarConfig, self.avatar, "avatar")
        super().__post_init__()
        if self.lambda_layer_cover < 0 or self.layer_cover_inset < 0:
            raise ValueError(f"need lambda_layer_cover >= 0 and layer_cover_inset >= 0, found "
                             f"{self.lambda_layer_cover} and {self.layer_cover_inset}")
        if self.lambda_normal_prior < 0:
            raise ValueError(f"lambda_normal_prior must be >= 0, found {self.lambda_normal_prior}")
        if self.seen_min_weight is not None and self.seen_min_weight <= 0:
            raise ValueError(f"seen_min_weight must be > 0 (pixels) or None, found {self.seen_min_weight}")
        trims = tuple(self.layer_hem_trims)
        if not all(0 < f < 1 for f in trims) or any(b <= a for a, b in zip(trims, trims[1:])):
            raise ValueError(f"layer_hem_trims must be increasing fractions of the stage in (0, 1), found {trims}")
        if self.layer_gap_reach < 0:
            raise ValueError(f"layer_gap_reach must be >= 0 grid steps (0: off), found {self.layer_gap_reach}")
        if self.fill_unseen_ring < 0:
            raise ValueError(f"fill_unseen_ring must be >= 0, found {self.fill_unseen_ring}")
        if not 0 <= self.lr_decay_start < 1 or not 0 < self.lr_final <= 1:
            raise ValueError(f"need 0 <= lr_decay_start < 1 and 0 < lr_final <= 1, found {self.lr_decay_start} "
                             f"and {self.lr_final}")

    def lr_schedule(self) -> Scheduled:
        if self.lr_milestones:
            return super().lr_schedule()
        return Scheduled.exponential(1.0, self.lr_decay_start, 1.0, self.lr_final)

    @classmethod
    def paper(cls, **kw) -> "Stage1Config":
        """The settings before the Stage I fidelity work (GaussianAvatar's schedule, every Gaussian
        decoded every step, the paper's Gaussians: ``AvatarConfig.paper()``), for comparisons."""
        base = dict(lr_milestones=(1 / 3, 2 / 3), cull_backfacing=None, fill_unseen=False, lambda_normal_prior=0.0,
                    seen_on_person=False, seen_min_weight=None, layer_off_person=False, layer_outline_cut=False,
                    layer_through=False,
                    layer_behind_limbs=False, limbs_over_cloth=False, layer_hidden_by_limbs=False,
                    layer_gap_reach=0, body_hidden_by_limbs=False, layer_hem_trims=(), layer_seen_inside=False,
                    layer_depth_match=False, seen_trained_only=False,
                    random_background=False,
                    avatar=AvatarConfig.paper())
        return cls(**{**base, **kw})

    @classmethod
    def from_dict(cls, d: dict):
        """Settings recorded by a run; records older than a setting get the value that run used."""
        d = dict(d)
        if "cull_backfacing" not in d:  # recorded before the Stage I fidelity work
            d["cull_backfacing"] = None
            if isinstance(d.get("avatar"), dict) and "splat" not in d["avatar"]:
                d["avatar"] = {**LEGACY_AVATAR, **d["avatar"]}
        d.setdefault("fill_unseen", False)  # recorded before Stage I filled its unseen side
        d.setdefault("random_background", False)  # recorded before training on random backgrounds
        d.setdefault("seen_on_person", False)  # recorded before the seen flags were recounted on the person
        d.setdefault("seen_min_weight", None)  # recorded before the recount counted blended Gaussians
        d.setdefault("layer_off_person", False)  # recorded before the layer's fill left off-person Gaussians empty
        d.setdefault("layer_outline_cut", False)  # recorded before the body under a side the outline cut took the cloth's colour
        d.setdefault("layer_through", False)  # recorded before the layer's fill told the body through it from cloth
        d.setdefault("layer_behind_limbs", False)  # recorded before layer Gaussians behind an arm took the cloth's colour
        d.setdefault("limbs_over_cloth", False)  # recorded before arm Gaussians by the layer in its colour were no source
        d.setdefault("layer_hidden_by_limbs", False)  # recorded before the layer hidden behind the arms was filled
        d.setdefault("layer_gap_reach", 0)  # recorded before gaps in the layer's seen cloth were filled along both ways
        d.setdefault("body_hidden_by_limbs", False)  # recorded before the body hidden behind the arms was filled
        d.setdefault("layer_hem_trims", ())  # recorded before the layer's hem was trimmed part way through
        d.setdefault("layer_seen_inside", False)  # recorded before layer Gaussians seen from inside were unseen
        d.setdefault("layer_depth_match", False)  # recorded before the layer's front and back matched its sides' depth
        d.setdefault("seen_trained_only", False)  # recorded before seen Gaussians training never coloured were unseen
        d.setdefault("lr_layer_skinning", 0.0)  # recorded before the garment layer's skinning was learned
        d.setdefault("lambda_normal_prior", 0.0)  # recorded before frames without normal maps had a normal prior
        d.setdefault("lambda_layer_cover", 0.0)  # recorded before the layer's cover prior existed
        if isinstance(d.get("avatar"), dict):  # avatar settings recorded before each existed
            d["avatar"] = {**AVATAR_BEFORE_SETTING, **d["avatar"]}
        return super().from_dict(d)


# avatar settings that runs recorded before the Stage I fidelity work used without naming them
LEGACY_AVATAR = dict(decode_resolution=None, splat="sphere", scale_floor=0.0, color_residual=False)
