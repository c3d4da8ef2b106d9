"""AvatarState: what training changes, apart from how a stage trains it.

It holds the avatar model (feature map S, decoder G, and in Stage II the pose encoder E), the
per-frame pose corrections, and the visibility flags: ``seen`` (Eq. 7, marked during Stage I) and
``trusted_seen`` (the flags shrunk on the UV grid that Stage II works with). Everything that
renders or exports an avatar asks it for Gaussians -- canonical or posed, at a video frame or at
any pose -- and ``frozen()`` gives a copy that no longer changes (exports while training goes on).

Edits (``reconstruct.edits``: lock, erase, recolour, redo, painted visibility) apply here, at one
place between the decoder and everything that renders, trains or exports: ``decode`` (locks and
colour edits, so training steps see them too), ``posed`` / ``posed_at`` / ``splats`` (erased
Gaussians at opacity 0), ``snapshot`` (erased rows dropped, ``Snapshot.ids`` naming the rest) and
the seen flags (``seen_flags()`` and ``trusted_seen`` return the painted map; the trained flags
stay underneath, in ``seen`` and the checkpoint).
"""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import torch

from ..appearance.propagation import erode_by_part
from ..body.base import BodyModel
from ..body.lbs import apply_normals
from ..body.parts import refinable_bone
from ..body.pose import BodyPose
from ..edits.edit_list import EditList
from ..snapshot import Snapshot
from .model import AvatarModel, CanonicalGaussians, PosedGaussians

SPACES = ("observation", "canonical")


def facing_hits(hits: torch.Tensor, posed: PosedGaussians, camera) -> torch.Tensor:
    """The entries of ``hits`` (Gaussian ids, repeats kept) whose posed Gaussian faces ``camera``:
    Eq. 7's facing test (``AvatarState.mark_seen``, the end-of-Stage-I recount)."""
    centre = torch.as_tensor(camera.center, dtype=posed.means.dtype, device=posed.means.device)
    return hits[((posed.means[hits] - centre) * posed.normals[hits]).sum(1) < 0]


class AvatarState:
    def __init__(self, body: BodyModel, model: AvatarModel, poses: list[BodyPose], *,
                 refine_poses: bool = False) -> None:
        self.body = body
        self.model = model
        self.poses = list(poses)  # the video's frame poses (fitted), corrected by pose_delta
        self.refine_poses = refine_poses
        J = body.num_joints
        self.pose_delta = torch.nn.Parameter(torch.zeros(len(self.poses), J + 2, 3, dtype=torch.float64))
        # which rows of a correction count (the bones refinement may turn, then the global rotation
        # and translation): a small bone's row gets no gradient and stays zero
        self.refinable = torch.tensor([refinable_bone(b) for b in body.bone_labels] + [True, True],
                                      dtype=torch.float64)[:, None]
        self.seen = torch.zeros(model.num_gaussians, dtype=torch.bool)
        self._trusted_seen: torch.Tensor | None = None  # Stage II's flags as computed (unpainted)
        # the seen Gaussians whose colours the fills may carry to the unseen ones (Stage I's finish:
        # not those seen by their blend weight alone, nor layer Gaussians that show the body); None:
        # all seen ones (runs from before it)
        self.colour_sources: torch.Tensor | None = None
        # (N,3) float: for the Gaussians in no training frame's image (past the edge of a photo
        # that cuts the person off) the colour the images show where their limb crosses the edge,
        # NaN for the others; set by Stage I's finish, given to the fills (``appearance/cut_fill``).
        # None: not counted (runs from before it)
        self.cut_colors: torch.Tensor | None = None
        # (N,3) float: for the Gaussians of a part the images cover but never show (a photo's neck
        # under the chin) the colour the images show where they project, NaN for the others; set by
        # Stage I's finish, given to the fills (``appearance/occluded_fill``). None: not read (runs
        # from before it)
        self.occluded_colors: torch.Tensor | None = None
        # (N,3) float: for the unseen Gaussians behind a photo's head, neck and back that hair worn
        # down covers, its colour as the images show it, NaN for the others; set by Stage I's
        # finish, given to the fills (``appearance/long_hair``). None: not read (runs from before it)
        self.hair_colors: torch.Tensor | None = None
        self.edits = EditList((), model.num_gaussians)
        self._transforms: dict[int, torch.Tensor] = {}
        self._articulations: dict[int, torch.Tensor] = {}

    @property
    def device(self) -> torch.device:
        return self.model.features.device

    @property
    def num_gaussians(self) -> int:
        return self.model.num_gaussians

    @property
    def num_frames(self) -> int:
        return len(self.poses)

    def check_frame(self, i: int) -> int:
        if not 0 <= i < len(self.poses):
            raise ValueError(f"frame {i} is out of range: the video has {len(self.poses)} frames (0..{len(self.poses) - 1})")
        return i

    # ----- poses ----------------------------------------------------------------------------
    def pose_transforms(self, pose: BodyPose) -> torch.Tensor:
        """(J,4,4) bone transforms of any pose of the body, on the model's device."""
        return self.body.bone_transforms(pose).float().to(self.device)

    def frame_transforms(self, i: int, refined: bool = True) -> torch.Tensor:
        """Bone transforms of video frame ``i``: with its pose correction when poses are refined
        (differentiable in ``pose_delta``), else the fitted pose's (cached)."""
        if refined and self.refine_poses:
            p, d = self.poses[i], self.pose_delta[i] * self.refinable
            f64 = dict(dtype=torch.float64)
            T = self.body.bone_transforms_t(torch.as_tensor(p.joint_rotations, **f64) + d[:-2],
                                            torch.as_tensor(p.global_orient, **f64) + d[-2],
                                            torch.as_tensor(p.transl, **f64) + d[-1])
            return T.float().to(self.device)
        if i not in self._transforms:
            self._transforms[i] = self.pose_transforms(self.poses[i])
        return self._transforms[i]

    def refined_pose(self, i: int) -> BodyPose:
        p = self.poses[i]
        d = (self.pose_delta[i].detach() * self.refinable).numpy()
        return BodyPose(p.joint_rotations + d[:-2], p.global_orient + d[-2], p.transl + d[-1])

    def articulation_of_pose(self, pose: BodyPose) -> torch.Tensor:
        """Bone transforms of a pose without its global rotation and translation (the pose
        encoder's input)."""
        return self.pose_transforms(BodyPose(pose.joint_rotations, np.zeros(3), np.zeros(3)))

    def articulation(self, frame: int | None) -> torch.Tensor:
        """``articulation_of_pose`` of video frame ``frame`` (cached), or of the canonical pose."""
        key = -1 if frame is None else frame
        if key not in self._articulations:
            self._articulations[key] = (self.body.canonical_transforms.float().to(self.device) if frame is None
                                        else self.articulation_of_pose(self.poses[frame]))
        return self._articulations[key]

    # ----- visibility flags (painted) -------------------------------------------------------
    @property
    def trusted_seen(self) -> torch.Tensor | None:
        """Stage II's seen flags (eroded Stage I flags) with the painted overrides applied: what
        view selection, propagation and the guidance losses use. Assigning sets the flags under
        the paint."""
        t = self._trusted_seen
        return None if t is None else self.edits.paint(t)

    @trusted_seen.setter
    def trusted_seen(self, flags: torch.Tensor | None) -> None:
        self._trusted_seen = flags

    def source_flags(self) -> torch.Tensor:
        """(N,) bool, not painted: the seen flags less those Stage I's finish took out of the colour
        sources (``colour_sources``); the seen flags when it set none."""
        return self.seen if self.colour_sources is None else self.seen & self.colour_sources

    def trusted_sources(self, neighbours: np.ndarray, erosion: int) -> torch.Tensor:
        """(N,) bool with the painted overrides: the Gaussians whose colours Stage II's
        pseudo-appearance and the editor carry to the others -- ``source_flags`` eroded by ``erosion``
        texels as the trusted flags are (``erode_by_part``), like the sources of Stage I's fill."""
        flags = erode_by_part(self.source_flags().cpu().numpy(), neighbours, self.model.parts(), erosion)
        return self.edits.paint(torch.as_tensor(flags))

    # ----- Gaussians ------------------------------------------------------------------------
    def decode(self, frame: int | None = None, pose: BodyPose | None = None, index: torch.Tensor | None = None
               ) -> tuple[CanonicalGaussians, torch.Tensor | None]:
        """G([S, S]) -- or with pose injection G([S, P]) for video frame ``frame`` / ``pose`` (the
        canonical pose when neither is given) -- and the pose features E(P_uv) (None without pose
        injection) for their regulariser; only the Gaussians ``index`` when given. Locks and colour
        edits are applied."""
        pf = None
        if self.model.pose_encoder is not None:
            art = self.articulation_of_pose(pose) if pose is not None else self.articulation(frame)
            pf = self.model.pose_features(art)
        canon = self.model.canonical(pf, index=index) if index is not None else self.model.canonical(pf)
        if self.edits:
            canon = self.edits.apply_canonical(canon, self, frame, pose)
        return canon, pf

    def canonical(self, frame: int | None = None, pose: BodyPose | None = None) -> CanonicalGaussians:
        return self.decode(frame, pose)[0]

    def posed(self, frame: int) -> PosedGaussians:
        """The avatar in observation space at video frame ``frame``."""
        return self.posed_with_surface_normals(frame, surface=False)[0]

    def posed_with_surface_normals(self, frame: int, *, surface: bool = True) -> tuple[PosedGaussians, torch.Tensor | None]:
        """``posed(frame)`` and, with ``surface``, the (N,3) normals of the surface each Gaussian sits
        on -- the body's or the garment layer's, posed the same way -- instead of the learned ones
        (which turn freely where no normal map pins them); one decode for both."""
        canonical, transforms = self.canonical(frame), self.frame_transforms(frame)
        if not surface:
            return self.edits.apply_posed(self.model.pose(canonical, transforms)), None
        matrices = self.model.lbs_matrices(transforms, canonical.index)  # one LBS for both
        posed = self.edits.apply_posed(self.model.pose_with(canonical, matrices))
        return posed, apply_normals(matrices, self.model.base_normals)

    def posed_at(self, pose: BodyPose) -> PosedGaussians:
        """The avatar at any pose of its body (novel poses, motion files)."""
        return self.edits.apply_posed(self.model.pose(self.canonical(pose=pose), self.pose_transforms(pose)))

    def splats(self, space: str = "observation", frame: int = 0) -> PosedGaussians:
        if space == "canonical":
            return self.edits.apply_posed(self.model.splats(self.canonical(None)))
        if space == "observation":
            return self.posed(frame)
        raise ValueError(f"snapshot space must be 'observation' or 'canonical', found {space!r}")

    def seen_flags(self) -> torch.Tensor:
        """The flags the visibility mode shows: Stage II's trusted ones once it has them, painted."""
        t = self.trusted_seen
        return t if t is not None else self.edits.paint(self.seen)

    def _snapshot(self, g: PosedGaussians, **meta) -> Snapshot:
        snap = Snapshot.from_gaussians(g, self.seen_flags(), **meta)
        erased = self.edits.erased
        if erased is None or not erased.any():
            return snap
        keep = ~erased
        arrays = {k: getattr(snap, k)[keep] for k in ("means", "scales", "rotations", "colors", "opacities",
                                                      "normals", "visibility")}
        return dataclasses.replace(snap, **arrays, ids=np.flatnonzero(keep).astype(np.int32))

    @torch.no_grad()
    def snapshot(self, space: str = "observation", frame: int = 0, **meta) -> Snapshot:
        """What renderers and exports draw: erased Gaussians left out (``Snapshot.ids`` names the
        Gaussian of each row then)."""
        return self._snapshot(self.splats(space, frame), space=space, frame_index=frame, **meta)

    @torch.no_grad()
    def snapshot_at_pose(self, pose: BodyPose, frame: int = 0, **meta) -> Snapshot:
        return self._snapshot(self.posed_at(pose), space="observation", frame_index=frame, **meta)

    # ----- copies and checkpoints -------------------------------------------------------------
    def frozen(self) -> "AvatarState":
        """A copy whose avatar no longer changes (model, pose corrections and flags copied; the
        body and the video's poses shared). Take it between training steps."""
        f = copy.copy(self)
        f.model = copy.deepcopy(self.model, memo={id(self.body): self.body})
        with torch.no_grad():
            f.pose_delta = torch.nn.Parameter(self.pose_delta.detach().clone(), requires_grad=False)
        f.seen = self.seen.clone()
        f._trusted_seen = None if self._trusted_seen is None else self._trusted_seen.clone()
        f.colour_sources = None if self.colour_sources is None else self.colour_sources.clone()
        f.cut_colors = None if self.cut_colors is None else self.cut_colors.clone()
        f.occluded_colors = None if self.occluded_colors is None else self.occluded_colors.clone()
        f.hair_colors = None if self.hair_colors is None else self.hair_colors.clone()
        f.edits = self.edits  # immutable
        f._transforms = dict(self._transforms)
        f._articulations = dict(self._articulations)
        return f

    def state_dict(self) -> dict:
        """Tensors and plain data: the model's, the pose corrections, the flags and -- with a garment
        layer -- the layer's geometry (``GarmentLayer.to_state``; checkpoints rebuild the model
        with it before loading, ``Trainer.load_state_dict``)."""
        out = {"model": self.model.state_dict(), "pose_delta": self.pose_delta.detach().clone(),
               "seen": self.seen.clone(),
               "trusted_seen": None if self._trusted_seen is None else self._trusted_seen.clone(),
               "colour_sources": None if self.colour_sources is None else self.colour_sources.clone(),
               "cut_colors": None if self.cut_colors is None else self.cut_colors.clone(),
               "occluded_colors": None if self.occluded_colors is None else self.occluded_colors.clone(),
               "hair_colors": None if self.hair_colors is None else self.hair_colors.clone()}
        if self.model.layer is not None:
            out["garment_layer"] = self.model.layer.to_state()
        return out

    def load_state_dict(self, state: dict) -> None:
        saved = state.get("garment_layer")
        layer = self.model.layer
        if (saved is None) != (layer is None) or (layer is not None and (
                list(layer.grid_shape) != list(saved.get("grid_shape", [])))):
            have = "no garment layer" if layer is None else f"a {layer.grid_shape[0]}x{layer.grid_shape[1]} garment layer"
            found = "none" if saved is None else f"{saved.get('grid_shape')}"
            raise ValueError(f"the avatar state holds a garment layer of grid {found}; this model has {have} "
                             f"(build the model with the state's layer first)")
        model_state = dict(state["model"])
        if self.model.layer is not None and "layer_skin_logit" not in model_state:
            # saved before the layer's skinning was learned: the built weights, i.e. zero factors
            model_state["layer_skin_logit"] = torch.zeros_like(self.model.layer_skin_logit)
        if self.model.layer is not None and "layer_trimmed" not in model_state:
            model_state["layer_trimmed"] = torch.zeros_like(self.model.layer_trimmed)  # saved before trimming existed
        if self.model.layer is not None and "layer_outline_cut" not in model_state:
            # saved before the outline's cut was recorded: none
            model_state["layer_outline_cut"] = torch.zeros_like(self.model.layer_outline_cut)
        self.model.load_state_dict(model_state)
        with torch.no_grad():
            self.pose_delta.copy_(state["pose_delta"])
        self.seen = state["seen"].clone()
        ts = state.get("trusted_seen")
        self._trusted_seen = None if ts is None else ts.clone()
        cs = state.get("colour_sources")  # absent in checkpoints from before it: all seen ones
        if cs is not None and tuple(cs.shape) != tuple(self.seen.shape):
            raise ValueError(f"the avatar state's colour_sources has shape {tuple(cs.shape)}; "
                             f"its seen flags have {tuple(self.seen.shape)}")
        self.colour_sources = None if cs is None else cs.clone().bool()
        self.cut_colors = self._colours_in(state, "cut_colors")  # absent in checkpoints from before it
        self.occluded_colors = self._colours_in(state, "occluded_colors")
        self.hair_colors = self._colours_in(state, "hair_colors")

    def _colours_in(self, state: dict, key: str) -> torch.Tensor | None:
        """``state[key]``, one colour per Gaussian (NaN where none), checked; None where absent."""
        cc = state.get(key)
        if cc is not None and tuple(cc.shape) != (len(self.seen), 3):
            raise ValueError(f"the avatar state's {key} has shape {tuple(cc.shape)}; "
                             f"expected ({len(self.seen)}, 3), one colour per Gaussian")
        return None if cc is None else cc.clone().float()

    def replace_model(self, model: AvatarModel) -> None:
        """Train ``model`` from now on (a model with a different garment layer, before a checkpoint
        is loaded into it): the per-Gaussian flags and the edits start over at its size."""
        self.model = model
        self.seen = torch.zeros(model.num_gaussians, dtype=torch.bool)
        self._trusted_seen = None
        self.colour_sources = None
        self.cut_colors = None
        self.occluded_colors = None
        self.hair_colors = None
        self.edits = EditList((), model.num_gaussians)

    @torch.no_grad()
    def mark_seen(self, first_hit: torch.Tensor, posed: PosedGaussians, camera) -> None:
        """Paper Eq. 7: a Gaussian is seen when it is the first hit of a training ray -- counted only
        where it faces the camera. Without the facing test, Gaussians on the back of thin limbs whose
        footprint spills past the outline are first hits on outline pixels and would be marked seen."""
        hits = facing_hits(torch.unique(first_hit[first_hit >= 0]), posed, camera)
        if len(hits):
            self.seen[hits.cpu()] = True
