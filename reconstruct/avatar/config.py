"""Avatar model configuration (paper Sec. 3.1, Appendix A.1; GaussianAvatar's channel counts).

The defaults depart from the paper's Gaussian shape and layout (see docs/design_notes.md, "Stage I
fidelity"): flat discs in the body's tangent frame with a scale floor from the local texel step,
one Gaussian per texel of a 256 x 256 map, decoded at 128 x 128 and interpolated, plus a
per-Gaussian colour residual. ``AvatarConfig.paper()`` gives the paper's layout (the previous
defaults): isotropic spheres, identity rotation, one decoded Gaussian per texel of a 128 x 128 map.
"""

from __future__ import annotations

from dataclasses import dataclass

SPLATS = ("disc", "sphere")
GARMENT_LAYER_MODES = ("off", "auto", "on")
DECODER_INITS = ("he", "torch")
# metres between a garment layer's rows (docs/loose_clothing.md, "A finer layer"; 1 cm since "Rows
# every centimetre, decoded at every other one")
GARMENT_LAYER_STEP = 0.010
# a one-tube garment layer's skinning-weight filter against garment_layer.weight_diffusion's
# (AvatarConfig.garment_filter_one_tube; docs/loose_clothing.md, "A one-tube layer's wider weight filter")
ONE_TUBE_FILTER = 1.5


@dataclass
class AvatarConfig:
    feature_channels: int = 64  # channels of the canonical feature map S (GaussianAvatar c_geom)
    feature_resolution: int = 128  # S is 128 x 128 (paper)
    gaussian_resolution: int = 256  # one Gaussian per valid texel of this positional map (paper: 512)
    # the decoder runs on the texel grid of this resolution (None, or not coarser than the
    # Gaussians' map: their own) and its outputs are interpolated bilinearly in UV to the Gaussians
    decode_resolution: int | None = 128
    hidden: int = 128  # decoder width (GaussianAvatar hsize)
    trunk_layers: int = 8  # paper: 8-layer MLP, skip from the input into the 4th layer
    skip_layer: int = 4
    head_layers: int = 2  # each head is a 2-layer MLP
    # the decoder's hidden weights: "he" (normal, std sqrt(2 / fan_in), zero biases) or "torch"
    # (PyTorch's Linear default, std 1/sqrt(3 fan_in): every softplus layer shrank the spread across
    # texels ~3x, so the decoder began giving every texel the same output and could stay so for
    # hundreds of steps -- GaussianDecoder). Runs recorded before it, and paper(), load as "torch"
    decoder_init: str = "he"
    offset_scale: float = 0.02  # metres per unit of the Δx head (GaussianAvatar)
    # Gaussian shape. "disc": flat, in the tangent plane of the (decoded) normal, axes along the UV
    # map's u and v steps, rotated with the body by LBS; "sphere": isotropic, identity rotation (paper)
    splat: str = "disc"
    scale_range: float = 3.0  # a Gaussian's std is at most this multiple of its own texel step
    scale_floor: float = 0.6  # ... and at least this multiple (0: none, the paper): neighbours overlap
    init_scale_factor: float = 0.8  # initial std as a multiple of its texel step
    disc_thickness: float = 0.25  # a disc's std along its normal as a fraction of its smaller in-plane std
    color_residual: bool = True  # a learned per-Gaussian colour offset (logit) on top of the decoded colour
    # the residual is this gain x its parameter: Adam moves a parameter by about its learning rate
    # per step, so the gain is the residual's learning rate relative to the decoder's
    color_residual_gain: float = 10.0
    feature_init_std: float = 0.01
    pose_feature_channels: int = 64  # P channels in Stage II (same as S so [S,P] has the Stage I width)
    # loose clothing (docs/loose_clothing.md): a second set of Gaussians on a tube round the hips and
    # legs, after the body's. "off": none; "auto": built at the start of training when the masks show
    # loose clothing (garment_layer.volume_hint_from_masks), none for tight clothing; "on": the same,
    # an error when they show none. Runs recorded before the layer existed load as "off"; so does
    # paper() (the paper has no layer).
    garment_layer: str = "auto"
    garment_opacity_init: float = 0.5  # initial opacity of the layer's Gaussians (the body's are 1)
    # a layer Gaussian's opacity is sigmoid(gain x its parameter), the parameter trained at the
    # decoder's learning rate: the gain is the opacity logit's learning rate relative to the decoder's
    garment_opacity_gain: float = 10.0
    # metres between the layer's rows; its columns are spaced alike round the hips (128 at 1 cm, 92
    # at 1.4 cm): rows every 2 cm (64 columns) could not carry a 4 cm check round to the unseen side
    garment_layer_step: float = GARMENT_LAYER_STEP
    # the layer's decoder runs at every k-th row and column of its grid, the Gaussians between
    # interpolating its outputs (layer_nodes.py; each keeps its own colour residual), as the body's
    # Gaussians interpolate its coarser decode map: a finer layer_step for the decoder cost of a
    # coarser one. 1: every layer Gaussian is its own decoder evaluation. 2 (default): a quarter of
    # the decoder evaluations; with rows every 1 cm a step costs less than the 1.4 cm layer decoded
    # at every Gaussian did (docs/loose_clothing.md, "Rows every centimetre, decoded at every other one")
    garment_decode_every: int = 2
    # the width of a one-tube layer's skinning-weight filter (a coat, a skirt, a dress: one piece
    # round both legs) against garment_layer.weight_diffusion's, which two-tube layers (trousers,
    # each tube following its own leg) keep: 1.5 times wider, every one-tube garment of the
    # benchmark gained 0.05-0.40 dB unseen in 800 steps (the trousers lost 0.25 with it), and
    # through the whole protocol the coats kept their PSNR with fewer holes, in the walk too.
    # Runs recorded before it load with 1
    garment_filter_one_tube: float = ONE_TUBE_FILTER
    # metres between the heights at which the layer's learned skinning has its own factors
    # (AvatarModel.layer_skin_weights; the rows between interpolate): one factor per row let the
    # hem rows, 5 mm apart, follow other bones than the row above and tear 5 cm off in the walk
    garment_skin_knot_step: float = 0.04
    # sectors round each tube at which the learned skinning has its own factors (interpolated
    # round the tube between them; at most one per column); 1: shared round the tube. 12 let an
    # open coat's front panels follow their own thighs (coat seed 1: walk holes 2.2 -> 1.7 %)
    garment_skin_sectors: int = 12
    # metres a garment layer's posed Gaussians are kept in front of the posed body surface it
    # covers (layer_clearance.py: the legs' own skinning turns them out through cloth skinned with
    # a blend); 0: off. Runs recorded before it load with 0
    garment_clearance: float = 0.005
    # a garment layer's discs grow round the ring and down the column by as much as the pose
    # stretches its grid there (its built grid posed by the layer's own skinning, against the
    # canonical steps; never shrunk, at most garment_max_stretch): cloth skinned with weights
    # blended across the legs stretches where the legs part, and discs sized for the canonical grid
    # let the background through in stripes between the rows (a photo's skirt swung to one side,
    # seen from behind). False: the canonical sizes in every pose. Runs recorded before it load
    # with False
    garment_stretch_scales: bool = True
    # ... by the stretch past this slack (a grid stretched 1.3 times still closes: the discs at the
    # scale floor, 0.6 of a step, overlap), at most garment_max_stretch
    garment_stretch_slack: float = 1.3
    garment_max_stretch: float = 3.0

    @classmethod
    def paper(cls, **kw) -> "AvatarConfig":
        """The paper's Gaussians and the earlier defaults: isotropic, identity rotation, no scale
        floor, one decoded Gaussian per texel of a 128 x 128 map, no colour residual."""
        base = dict(gaussian_resolution=128, decode_resolution=None, splat="sphere", scale_floor=0.0,
                    init_scale_factor=0.6, color_residual=False, garment_layer="off", decoder_init="torch")
        return cls(**{**base, **kw})

    @property
    def decoded_resolution(self) -> int:
        """The decode grid's resolution: ``decode_resolution``, never finer than the Gaussians' map."""
        return int(min(self.decode_resolution or self.gaussian_resolution, self.gaussian_resolution))

    def __post_init__(self) -> None:
        for name in ("feature_channels", "feature_resolution", "gaussian_resolution", "hidden", "trunk_layers"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"AvatarConfig.{name} must be positive, found {getattr(self, name)}")
        if self.decode_resolution is not None and self.decode_resolution < 8:
            raise ValueError(f"AvatarConfig.decode_resolution must be at least 8 or None, found {self.decode_resolution}")
        if not 1 <= self.skip_layer < self.trunk_layers:
            raise ValueError(f"AvatarConfig.skip_layer must be in [1, {self.trunk_layers}), found {self.skip_layer}")
        if not self.garment_stretch_slack >= 1.0:
            raise ValueError(f"AvatarConfig.garment_stretch_slack must be at least 1, found {self.garment_stretch_slack}")
        if not self.garment_max_stretch >= 1.0:
            raise ValueError(f"AvatarConfig.garment_max_stretch must be at least 1, found {self.garment_max_stretch}")
        if self.decoder_init not in DECODER_INITS:
            raise ValueError(f"AvatarConfig.decoder_init must be one of {', '.join(DECODER_INITS)}, "
                             f"found {self.decoder_init!r}")
        if self.splat not in SPLATS:
            raise ValueError(f"AvatarConfig.splat must be one of {', '.join(SPLATS)}, found {self.splat!r}")
        if not 0 <= self.scale_floor < self.init_scale_factor < self.scale_range:
            raise ValueError(f"AvatarConfig: need 0 <= scale_floor < init_scale_factor < scale_range, found "
                             f"{self.scale_floor}, {self.init_scale_factor} and {self.scale_range}")
        if not 0 < self.disc_thickness <= 1:
            raise ValueError(f"AvatarConfig.disc_thickness must be in (0, 1], found {self.disc_thickness}")
        if self.garment_layer not in GARMENT_LAYER_MODES:
            raise ValueError(f"AvatarConfig.garment_layer must be one of {', '.join(GARMENT_LAYER_MODES)}, "
                             f"found {self.garment_layer!r}")
        if not 0 < self.garment_opacity_init < 1 or not self.garment_opacity_gain > 0:
            raise ValueError(f"AvatarConfig: need 0 < garment_opacity_init < 1 and garment_opacity_gain > 0, found "
                             f"{self.garment_opacity_init} and {self.garment_opacity_gain}")
        if not 0.01 <= self.garment_skin_knot_step <= 1.0:
            raise ValueError(f"AvatarConfig.garment_skin_knot_step must be in [0.01, 1] metres, found "
                             f"{self.garment_skin_knot_step}")
        if not (isinstance(self.garment_skin_sectors, int) and 1 <= self.garment_skin_sectors <= 64):
            raise ValueError(f"AvatarConfig.garment_skin_sectors must be an integer in [1, 64], found "
                             f"{self.garment_skin_sectors!r}")
        if not (isinstance(self.garment_decode_every, int) and 1 <= self.garment_decode_every <= 8):
            raise ValueError(f"AvatarConfig.garment_decode_every must be an integer in [1, 8], found "
                             f"{self.garment_decode_every!r}")
        if not 0.25 <= self.garment_filter_one_tube <= 4.0:
            raise ValueError(f"AvatarConfig.garment_filter_one_tube must be in [0.25, 4] (times the filter of "
                             f"garment_layer.weight_diffusion), found {self.garment_filter_one_tube}")
        if not 0.005 <= self.garment_layer_step <= 0.1:
            raise ValueError(f"AvatarConfig.garment_layer_step must be in [0.005, 0.1] metres, found "
                             f"{self.garment_layer_step}")
        if self.pose_feature_channels != self.feature_channels:
            raise ValueError("AvatarConfig.pose_feature_channels must equal feature_channels: P replaces the second S")
