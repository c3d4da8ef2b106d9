"""The synthetic benchmark scene: an Anny body in painted clothes walking in place in front of one
camera, with evaluation cameras all around (ground truth for the views the video never saw).

The clothing model (``SyntheticConfig.clothing``, see clothing.py) is ``garment`` by default
(backs inferable from fronts) or ``independent`` (the original scene: random backs; the same
images as before for a seed). Every unseen evaluation view carries the front-leak ("tattoo")
information of reconstruct.metrics.front_leak in ``EvalView.front_leak``.

Loose clothing (``clothing=skirt|coat|dress|wide_trousers``, LOOSE_GARMENTS): the body is painted
with the garment model and wears a garment with geometry (garment_mesh.py: a closed shell built
round the body's hull, garment_skinning.py: weights blended across the legs, garment_paint.py: its
colours), rendered together with the body (loose_outfit.py). The body, its motion and the cameras
are those of the ``garment`` scene of the same seed. With ``fit=painted`` the garment's colours are
painted on the body under it instead (garment_paint.painted_fit_texture) and no mesh is worn: the
tight scene in the loose garment's own pattern, to tell what the pattern costs from what the cloth's
volume costs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from ...body.anny_backend import random_phenotype
from ...body.base import vertex_normals
from ...camera import Camera, angle_between_views
from ..scene import BodySpec, EvalView, Frame, Scene
from .clothing import CLOTHING_MODELS, LEAK_DETAILS, PaintedClothing, check_hair, paint_clothing
from .garment_mesh import LOOSE_GARMENTS
from .motion import walk_in_place

GARMENT_FITS = ("loose", "painted")


@dataclass(frozen=True)
class SyntheticConfig:
    seed: int = 0
    num_frames: int = 60  # 3 s at 20 fps
    fps: float = 20.0
    image_size: int = 512
    num_eval_azimuths: int = 12  # every 30 degrees
    eval_frames: int = 3  # poses per evaluation camera, evenly spread over the clip
    seen_angle_deg: float = 45.0  # evaluation views within this angle of the training camera are "seen"
    distance: float = 3.6
    elevation_deg: float = 4.0
    fov_y_deg: float = 32.0
    texture_size: int = 512
    supersample: int = 2
    leg_spread_deg: float = 5.0
    clothing: str = "garment"  # "garment" (backs continue the fronts), "independent" (random backs) or a loose garment
    # a loose garment worn "loose" (its mesh, standing off the body) or "painted" (its colours painted
    # on the body under it, no mesh: the tight reference in the same pattern)
    fit: str = "loose"
    # the hair: "drawn" (the painter's own cut) or "long" (worn down over the back and shoulders,
    # painted on the body; clothing.py's HAIR_STYLES)
    hair: str = "drawn"

    def __post_init__(self) -> None:
        if self.clothing not in CLOTHING_MODELS + LOOSE_GARMENTS:
            raise ValueError(f"synthetic scene: clothing must be one of {', '.join(CLOTHING_MODELS + LOOSE_GARMENTS)}, "
                             f"found {self.clothing!r}")
        if self.fit not in GARMENT_FITS:
            raise ValueError(f"synthetic scene: fit must be one of {', '.join(GARMENT_FITS)}, found {self.fit!r}")
        if self.fit != "loose" and self.clothing not in LOOSE_GARMENTS:
            raise ValueError(f"synthetic scene: fit={self.fit} needs a loose garment "
                             f"(clothing={'|'.join(LOOSE_GARMENTS)}), found clothing={self.clothing}")
        check_hair(self.hair, self.clothing, "synthetic scene: ")
        if self.num_frames < 1:
            raise ValueError(f"synthetic scene: num_frames must be >= 1, found {self.num_frames}")
        if self.image_size < 32:
            raise ValueError(f"synthetic scene: image_size must be >= 32, found {self.image_size}")
        if self.num_eval_azimuths < 1 or self.eval_frames < 1:
            raise ValueError("synthetic scene: need at least one evaluation azimuth and frame")

    @property
    def garment_mesh(self) -> bool:
        """Whether the scene's person wears a garment with geometry (a loose garment, fit=loose)."""
        return self.clothing in LOOSE_GARMENTS and self.fit == "loose"


def quantize(image: np.ndarray) -> np.ndarray:
    """Round to 8 bits so the in-memory scene equals the one written to PNG files."""
    return (np.round(np.clip(image, 0.0, 1.0) * 255.0) / 255.0).astype(np.float32)


def quantize_normals(normal: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Camera-space normals rounded as the 8-bit encoding of scene files would (0 outside the mask)."""
    return (2.0 * quantize(0.5 * (normal + 1.0)) - 1.0) * (mask[..., None] > 0)


def check_body_in_view(camera: Camera, points: np.ndarray, what: str, min_inside: float = 0.5) -> None:
    uv, z = camera.project(points)
    inside = (z > camera.near) & (uv[:, 0] >= 0) & (uv[:, 0] < camera.width) & (uv[:, 1] >= 0) & (uv[:, 1] < camera.height)
    if inside.mean() < min_inside:
        raise ValueError(f"{what}: camera {camera.name!r} sees only {100 * inside.mean():.0f}% of the body's joints "
                         f"(expected at least {100 * min_inside:.0f}%); the camera does not see the body")


def build_synthetic_scene(config: SyntheticConfig = SyntheticConfig(), *, progress: bool = True) -> Scene:
    from renderer.gl_context import shared_offscreen_context
    from renderer.mesh_renderer import MeshRenderer

    rng = np.random.default_rng(config.seed)
    spec = BodySpec.anny(random_phenotype(rng), config.leg_spread_deg)
    body = spec.build()
    loose = config.clothing in LOOSE_GARMENTS
    painted = paint_clothing(body, rng, config.texture_size, "garment" if loose else config.clothing, config.hair)
    texture = painted.texture
    outfit = painted_garment = None
    if config.garment_mesh:
        from .loose_outfit import dress

        outfit = dress(body, config.clothing, painted, config.seed, config.texture_size)
        texture = outfit.body_texture
    elif loose:  # fit=painted: the garment's colours on the body, no mesh (so no skinning)
        from .garment_paint import painted_fit_texture
        from .loose_outfit import garment_pattern

        garment, colours, garment_texture = garment_pattern(body, config.clothing, config.seed, config.texture_size)
        texture = painted_fit_texture(body, painted, garment, colours, garment_texture, config.texture_size)
        painted_garment = {**colours.description, "version": _garment_version()}
    poses = walk_in_place(body.bone_labels, config.num_frames, config.fps, rng)

    z = body.canonical_vertices[:, 2].numpy()
    target = np.array([0.0, 0.0, 0.5 * (z.min() + z.max())])
    cam_kw = dict(width=config.image_size, height=config.image_size, fov_y_deg=config.fov_y_deg)
    train_cam = Camera.orbit(0.0, config.elevation_deg, config.distance, target, name="train", **cam_kw)

    ctx = shared_offscreen_context()
    if outfit is not None:
        mesh = outfit.renderer(ctx, supersample=config.supersample)
    else:
        faces = body.faces.numpy()
        corner_uvs = body.uv_coords.numpy()[body.face_uv_indices.numpy()]
        mesh = MeshRenderer(ctx, faces, corner_uvs, texture, supersample=config.supersample)

    def render(pose, camera, what):
        check_body_in_view(camera, body.posed_joints(pose).numpy(), what)
        verts, normals = posed_person(body, outfit, pose)
        out = mesh.render(verts, normals, camera)
        mask = quantize(out.mask)
        return quantize(out.rgb), mask, quantize_normals(out.normal, mask)

    eval_azimuths = [360.0 * k / config.num_eval_azimuths for k in range(config.num_eval_azimuths)]
    eval_frames = np.linspace(0, config.num_frames - 1, config.eval_frames + 2)[1:-1].round().astype(int)
    total = config.num_frames + len(eval_azimuths) * len(eval_frames)
    bar = tqdm(total=total, desc=f"synthetic scene seed={config.seed}", disable=not progress, unit="img")
    try:
        frames = []
        for i, pose in enumerate(poses):
            rgb, mask, normal = render(pose, train_cam, f"frame {i}")
            frames.append(Frame(i, rgb, mask, train_cam, pose, normal, time=i / config.fps))
            bar.update()
        views = []
        for az in eval_azimuths:
            cam = Camera.orbit(az, config.elevation_deg, config.distance, target, name=f"eval_az{az:03.0f}", **cam_kw)
            angle = angle_between_views(cam, train_cam, target)
            for fi in eval_frames:
                rgb, mask, normal = render(poses[fi], cam, f"evaluation view {cam.name} frame {fi}")
                views.append(EvalView(cam, int(fi), rgb, mask, normal, seen=angle <= config.seen_angle_deg, azimuth_deg=az))
                bar.update()
    finally:
        bar.close()
        mesh.release()
    meta = {"source": "synthetic", "seed": config.seed, "config": config.__dict__, "texture": texture,
            "target": target.tolist(), "clothing": painted.description}
    if outfit is not None:
        meta["loose_garment"] = {**outfit.colours.description, "version": _garment_version(),
                                 "garment_vertices": int(len(outfit.garment.vertices)),
                                 "garment_faces": int(len(outfit.garment.faces)),
                                 "top_m": round(outfit.garment.info["top_m"], 4),
                                 "hem_m": round(outfit.garment.info["hem_m"], 4)}
    if painted_garment is not None:
        meta["painted_garment"] = painted_garment
    scene = Scene(synthetic_scene_name(config), spec, frames, views, config.fps, meta)
    add_front_leak(scene, painted, config, outfit)
    return scene


def synthetic_scene_name(config: SyntheticConfig) -> str:
    """``synthetic-seedS`` for the original (independent) clothes -- the name runs trained before the
    garment model recorded in their checkpoints -- and ``synthetic-seedS-garment`` for garments, so
    that a checkpoint of one is refused on the other."""
    return (f"synthetic-seed{config.seed}" + ("" if config.clothing == "independent" else f"-{config.clothing}")
            + ("" if config.fit == "loose" else f"-{config.fit}") + ("" if config.hair == "drawn" else f"-{config.hair}hair"))


def _garment_version() -> int:
    from .loose_outfit import GARMENT_VERSION

    return GARMENT_VERSION


def repaint(config: SyntheticConfig) -> PaintedClothing:
    """The clothing of ``config``'s scene, painted again (no rendering): the same draws as the build.
    For a loose garment: the painting of the body under it (clothing.py's garment model; the leak
    regions are those of the body, the garment hides them when rendered)."""
    rng = np.random.default_rng(config.seed)
    spec = BodySpec.anny(random_phenotype(rng), config.leg_spread_deg)
    model = "garment" if config.clothing in LOOSE_GARMENTS else config.clothing
    return paint_clothing(spec.build(), rng, config.texture_size, model, config.hair)


def synthetic_config_of(scene: Scene) -> SyntheticConfig:
    """The SyntheticConfig a synthetic scene was built from; a clear error for any other scene
    (only a synthetic scene's ground truth can be rendered in new poses)."""
    if scene.meta.get("source") != "synthetic" or "config" not in scene.meta:
        raise ValueError(f"scene {scene.name!r} is not a synthetic scene: its ground truth in new poses (novel-pose "
                         "coverage needs a synthetic scene) exists only for `synthetic:` scenes")
    return SyntheticConfig(**scene.meta["config"])


def posed_person(body, outfit, pose) -> tuple[np.ndarray, np.ndarray]:
    """(V,3) vertices and normals of the person in ``pose``: the body and its LooseOutfit's garment
    as one mesh (``outfit.faces``), or the body alone (``body.faces``) when ``outfit`` is None."""
    if outfit is not None:
        return outfit.posed(pose)
    v = body.posed_vertices(pose)
    return v.numpy(), vertex_normals(v, body.faces).numpy()


def loose_outfit_of(scene: Scene):
    """The LooseOutfit of a synthetic loose-clothing scene (rebuilt from its configuration), or None."""
    cfg = scene.meta.get("config") or {}
    if scene.meta.get("source") != "synthetic" or cfg.get("clothing") not in LOOSE_GARMENTS:
        return None
    config = SyntheticConfig(**cfg)  # scenes made before `fit` existed read as fit=loose
    if not config.garment_mesh:
        return None
    from .loose_outfit import dress

    rng = np.random.default_rng(config.seed)
    spec = BodySpec.anny(random_phenotype(rng), config.leg_spread_deg)
    body = spec.build()
    painted = paint_clothing(body, rng, config.texture_size, "garment")
    return dress(body, config.clothing, painted, config.seed, config.texture_size)


def _mesh_renderer(body, texture: np.ndarray, supersample: int, ambient: float = 0.85):
    from renderer.gl_context import shared_offscreen_context
    from renderer.mesh_renderer import MeshRenderer

    corner_uvs = body.uv_coords.numpy()[body.face_uv_indices.numpy()]
    return MeshRenderer(shared_offscreen_context(), body.faces.numpy(), corner_uvs, texture,
                        supersample=supersample, ambient=ambient)


def render_scene_views(scene: Scene, texture: np.ndarray, views, *, supersample: int = 2,
                       ambient: float = 0.85, outfit=None) -> list[np.ndarray]:
    """The scene's body in the pose and camera of each of ``views`` (evaluation views or frames),
    rendered with another albedo atlas (as the ground truth is with ``scene.meta['texture']``):
    (H,W,3) float32 RGB over black, 8-bit rounded. In a loose-clothing scene the garment is drawn
    too, in black: it hides what it covers (``outfit``: the scene's LooseOutfit when the caller
    has it; else rebuilt from the scene's configuration)."""
    outfit = outfit if outfit is not None else loose_outfit_of(scene)
    body = outfit.body if outfit is not None else scene.body_model()
    if outfit is not None:
        from renderer.gl_context import shared_offscreen_context

        mesh = outfit.renderer(shared_offscreen_context(), supersample=supersample, ambient=ambient,
                               body_texture=texture, garment_texture=np.zeros_like(outfit.garment_texture))
    else:
        mesh = _mesh_renderer(body, texture, supersample, ambient)
    try:
        out = []
        for v in views:
            pose = scene.frames[getattr(v, "frame_index", getattr(v, "index", 0))].pose
            verts, normals = posed_person(body, outfit, pose)
            out.append(quantize(mesh.render(verts, normals, v.camera).rgb))
        return out
    finally:
        mesh.release()


def render_truth_masks(scene: Scene, poses, cameras, *, outfit=None) -> tuple[list[np.ndarray], list[np.ndarray] | None]:
    """Ground-truth coverage of a synthetic scene's person in any ``poses`` (BodyPose of the scene's
    body), each seen by the camera of the same index in ``cameras``, rendered as the scene's own
    masks are (its supersampling; not quantised): (H,W) float32 masks of the whole person, and --
    in a loose-clothing scene -- of the garment alone (its whole silhouette, also where the body is
    in front of it; None in a tight scene). ``outfit``: the scene's LooseOutfit when the caller has
    it; else rebuilt from the scene's configuration."""
    from renderer.gl_context import shared_offscreen_context

    config = synthetic_config_of(scene)
    if len(poses) != len(cameras):
        raise ValueError(f"render_truth_masks: {len(poses)} poses but {len(cameras)} cameras")
    outfit = outfit if outfit is not None else loose_outfit_of(scene)
    body = outfit.body if outfit is not None else scene.body_model()
    ctx = shared_offscreen_context()
    blank = np.zeros((8, 8, 3), np.uint8)
    if outfit is not None:
        whole = outfit.renderer(ctx, supersample=config.supersample)
        garment = outfit.renderer(ctx, supersample=config.supersample, garment_only=True)
    else:
        whole, garment = _mesh_renderer(body, blank, config.supersample), None
    try:
        masks, garment_masks = [], ([] if garment is not None else None)
        for pose, camera in zip(poses, cameras):
            verts, normals = posed_person(body, outfit, pose)
            masks.append(whole.render(verts, normals, camera).mask.astype(np.float32))
            if garment is not None:
                garment_masks.append(garment.render(verts, normals, camera).mask.astype(np.float32))
        return masks, garment_masks
    finally:
        whole.release()
        if garment is not None:
            garment.release()


def add_front_leak(scene: Scene, painted: PaintedClothing, config: SyntheticConfig, outfit=None) -> None:
    """Give every unseen evaluation view of ``scene`` its front-leak information: the image regions
    where the front-only details would land on the back (the leak atlas rendered unlit in the view's
    pose and camera, 8-bit rounded as a scene file stores it) and the details' colours."""
    from ...metrics.front_leak import FrontLeakInfo

    unseen = [v for v in scene.eval_views if not v.seen]
    regions = render_scene_views(scene, painted.leak_atlas, unseen, supersample=config.supersample, ambient=1.0,
                                 outfit=outfit)
    K = len(LEAK_DETAILS)
    for v, r in zip(unseen, regions):
        v.front_leak = FrontLeakInfo(LEAK_DETAILS, r[..., :K], tuple(painted.leak_colors[k] for k in LEAK_DETAILS))
    scene.meta["front_leak"] = {"details": list(LEAK_DETAILS), "version": 1}


def angle_to_seen(azimuth_deg: float) -> float:
    """Smallest angle between an azimuth and the frontal training direction (degrees)."""
    a = abs((azimuth_deg + 180.0) % 360.0 - 180.0)
    return a if not math.isnan(a) else 180.0
