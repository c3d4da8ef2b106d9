"""EditList: the applied edits, in order, and how they change the avatar's Gaussians.

Applied at one place, ``AvatarState`` (decode, posed, snapshot, the seen flags):

1. **Locks** (raw attributes): a locked texel's means, normals, colours, scales and Δx (and a garment
   layer Gaussian's opacity) come from the model's parameters at lock time (a frozen copy decoding
   at the same frame or pose), replacing the live decoder's output -- so the training loss has no
   gradient through those rows, and what the shared decoder and feature map learn later does not
   reach them. A texel under several locks
   keeps the first one's (it already rendered that way when the later lock was made).
2. **Colour edits** in list order: recolour (HSV) and redo (a per-texel logit offset that made the
   colour equal the prior's pseudo-colour when it was made; training moves it on from there).
3. **Erase**: opacity 0 in posed Gaussians (renders, view selection, evaluation); the rows are
   dropped from snapshots (exports).
4. **Visibility paint** (seen / unseen / redo) in list order over the flags Stage II uses.

An ``EditList`` is immutable: undo is the list without its last entry, so the avatar comes back
bit-exactly.
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import threading
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import numpy as np
import torch

from .colour import recolour
from .ops import Erase, Lock, Op, PaintSeen, PaintUnseen, Recolour, Redo

if TYPE_CHECKING:
    from ..avatar.model import AvatarModel, CanonicalGaussians, PosedGaussians
    from ..body.pose import BodyPose


class DecodingAvatar(Protocol):
    """What a lock needs of the avatar it holds (``AvatarState`` is one): its model and the pose
    encoder's input at a frame or pose."""

    model: AvatarModel

    def articulation(self, frame: int | None) -> torch.Tensor: ...

    def articulation_of_pose(self, pose: BodyPose) -> torch.Tensor: ...

LOCKED_FIELDS = ("means", "normals", "colors", "scales", "offsets_raw")
CACHE_LIMIT = 96  # decoded frames kept per lock (Stage II: the frozen copy decodes per frame)


@dataclass(frozen=True, eq=False)
class EditEntry:
    """One edit: ``op`` on the Gaussians of ``mask`` ((N,) bool, one per texel)."""

    id: int
    op: Op
    mask: np.ndarray
    label: str = ""  # how the selection was made ("part=head", "rect=... @front")
    created: str = ""
    color_offset: np.ndarray | None = None  # Redo: (k,3) float32 logit offsets of the k masked texels
    lock_params: dict[str, np.ndarray] | None = None  # Lock: the model's parameters at lock time
    _runtime: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def count(self) -> int:
        return int(self.mask.sum())

    def describe(self) -> str:
        return f"#{self.id} {self.op.describe()} {self.count} Gaussians" + (f" ({self.label})" if self.label else "")

    # ----- runtime helpers (built lazily, per device) -------------------------------------------
    def mask_on(self, device) -> torch.Tensor:
        key = ("mask", str(device))
        if key not in self._runtime:
            self._runtime[key] = torch.as_tensor(self.mask, device=device)
        return self._runtime[key]

    def offsets_on(self, device) -> torch.Tensor:
        """Redo's offsets as an (N,3) tensor (zero outside the mask)."""
        key = ("offsets", str(device))
        if key not in self._runtime:
            full = np.zeros((len(self.mask), 3), np.float32)
            full[self.mask] = self.color_offset
            self._runtime[key] = torch.as_tensor(full, device=device)
        return self._runtime[key]

    def frozen_model(self, template: AvatarModel) -> AvatarModel:
        """A copy of ``template`` holding the parameters this lock was made with."""
        with self._runtime.setdefault("lock", threading.Lock()):
            m = self._runtime.get("model")
            if m is None:
                m = build_frozen_model(template, self.lock_params)
                self._runtime["model"] = m
                self._runtime["cache"] = {}
            return m

    @torch.no_grad()
    def locked_values(self, state: DecodingAvatar, frame: int | None, pose: BodyPose | None) -> CanonicalGaussians:
        """All Gaussians as the model decoded them at lock time, at video frame ``frame`` or at
        ``pose`` (the same whatever the pose when the model had no pose encoder then)."""
        m = self.frozen_model(state.model)
        key = "canonical" if m.pose_encoder is None else (None if pose is not None else ("frame", frame))
        cache = self._runtime["cache"]
        if key is not None and key in cache:
            return cache[key]
        pf = None
        if m.pose_encoder is not None:
            art = state.articulation_of_pose(pose) if pose is not None else state.articulation(frame)
            pf = m.pose_features(art)
        out = m.canonical(pf)
        if key is not None:
            if len(cache) >= CACHE_LIMIT:
                cache.pop(next(iter(cache)))
            cache[key] = out
        return out


def model_parameters(model: AvatarModel) -> dict[str, np.ndarray]:
    """The model's trainable parameters as float32 arrays (what a lock keeps)."""
    return {k: p.detach().cpu().numpy().copy() for k, p in model.named_parameters()}


def build_frozen_model(template: AvatarModel, params: dict[str, np.ndarray]) -> AvatarModel:
    """A copy of ``template`` (buffers, config) with ``params`` (``model_parameters`` of the model
    at lock time): without a pose encoder when the locked one had none."""
    pose_encoder = template.pose_encoder
    had_encoder = any(k.startswith("pose_encoder.") for k in params)
    if had_encoder and pose_encoder is None:
        raise ValueError("a lock was made on a model with a pose encoder; this model has none")
    try:
        template.pose_encoder = pose_encoder if had_encoder else None
        m = copy.deepcopy(template)
    finally:
        template.pose_encoder = pose_encoder
    names = dict(m.named_parameters())
    if set(names) != set(params):
        missing, extra = sorted(set(names) - set(params)), sorted(set(params) - set(names))
        raise ValueError(f"a lock's parameters do not fit this model (missing {missing[:4]}, unknown {extra[:4]})")
    with torch.no_grad():
        for k, p in names.items():
            v = params[k]
            if tuple(v.shape) != tuple(p.shape):
                raise ValueError(f"a lock's parameter {k} has shape {tuple(v.shape)}, the model's {tuple(p.shape)}")
            p.copy_(torch.as_tensor(v))
            p.requires_grad_(False)
            p.grad = None
    return m.eval()


class EditList:
    """The applied edits in order (immutable: ``appended`` / ``without_last`` make new lists)."""

    def __init__(self, entries: tuple[EditEntry, ...] | list[EditEntry] = (), num_gaussians: int | None = None) -> None:
        self.entries = tuple(entries)
        for e in self.entries:
            if num_gaussians is not None and len(e.mask) != num_gaussians:
                raise ValueError(f"edit #{e.id}: mask of {len(e.mask)} texels for an avatar of {num_gaussians}")
            num_gaussians = len(e.mask)
        self.num_gaussians = num_gaussians
        self._cache: dict = {}

    def __len__(self) -> int:
        return len(self.entries)

    def __bool__(self) -> bool:
        return bool(self.entries)

    def __iter__(self):
        return iter(self.entries)

    def appended(self, entry: EditEntry) -> "EditList":
        return EditList(self.entries + (entry,), self.num_gaussians)

    def without_last(self) -> "EditList":
        return EditList(self.entries[:-1], self.num_gaussians)

    # ----- masks --------------------------------------------------------------------------
    def _union(self, kind: type) -> np.ndarray | None:
        masks = [e.mask for e in self.entries if isinstance(e.op, kind)]
        return np.logical_or.reduce(masks) if masks else None

    @property
    def erased(self) -> np.ndarray | None:
        """(N,) bool of erased Gaussians, None without an erase."""
        if "erased" not in self._cache:
            self._cache["erased"] = self._union(Erase)
        return self._cache["erased"]

    @property
    def redone(self) -> np.ndarray | None:
        """(N,) bool of Gaussians under a redo, None without one: the prior's appearance fills them
        without mirrored detail (the user said what was carried there is wrong)."""
        if "redone" not in self._cache:
            self._cache["redone"] = self._union(Redo)
        return self._cache["redone"]

    @property
    def locked(self) -> np.ndarray | None:
        if "locked" not in self._cache:
            self._cache["locked"] = self._union(Lock)
        return self._cache["locked"]

    def visibility_override(self) -> np.ndarray | None:
        """(N,) int8: +1 painted seen, -1 painted unseen (unseen and redo), 0 left as trained; the
        last paint of a texel wins. None when nothing is painted."""
        if "override" not in self._cache:
            out = None
            for e in self.entries:
                if isinstance(e.op, (PaintSeen, PaintUnseen, Redo)):
                    out = np.zeros(len(e.mask), np.int8) if out is None else out
                    out[e.mask] = 1 if isinstance(e.op, PaintSeen) else -1
            self._cache["override"] = out
        return self._cache["override"]

    def visibility_key(self) -> str:
        """A digest of the painted overrides ("" when none): what Stage II's view selection and
        propagated appearance were computed for."""
        o = self.visibility_override()
        return "" if o is None or not o.any() else hashlib.sha1(o.tobytes()).hexdigest()[:16]

    def paint(self, flags: torch.Tensor) -> torch.Tensor:
        """The seen flags with the painted overrides applied (a new tensor; ``flags`` unchanged)."""
        o = self.visibility_override()
        if o is None:
            return flags
        ot = torch.as_tensor(o, device=flags.device)
        return torch.where(ot > 0, torch.ones_like(flags), torch.where(ot < 0, torch.zeros_like(flags), flags))

    # ----- Gaussians ----------------------------------------------------------------------
    def apply_canonical(self, canon: CanonicalGaussians, state: DecodingAvatar, frame: int | None = None,
                        pose: BodyPose | None = None) -> CanonicalGaussians:
        """Locks, then colour edits, on decoded Gaussians (all, or those of ``canon.index``)."""
        if not any(isinstance(e.op, (Lock, Recolour, Redo)) for e in self.entries):
            return canon
        device = canon.means.device
        idx = canon.index
        rows = (lambda t: t) if idx is None else (lambda t: t[idx])
        out = {k: getattr(canon, k) for k in LOCKED_FIELDS}
        claimed = None
        for e in self.entries:
            if not isinstance(e.op, Lock):
                continue
            m = rows(e.mask_on(device))
            if claimed is not None:
                m = m & ~claimed
            if not bool(m.any()):
                continue
            frozen = e.locked_values(state, frame, pose)
            for k in LOCKED_FIELDS:
                v = rows(getattr(frozen, k))
                out[k] = torch.where(m[:, None], v, out[k].expand_as(v))
            if canon.opacities is not None and frozen.opacities is not None:  # a garment layer's opacities
                v = rows(frozen.opacities)
                out["opacities"] = torch.where(m, v, out.get("opacities", canon.opacities))
            claimed = m if claimed is None else claimed | m
        colors = out["colors"]
        for e in self.entries:
            if not isinstance(e.op, (Recolour, Redo)):
                continue
            sel = torch.nonzero(rows(e.mask_on(device)))[:, 0]
            if len(sel) == 0:
                continue
            c = colors[sel]
            if isinstance(e.op, Recolour):
                new = recolour(c, e.op.hue, e.op.saturation, e.op.value)
            else:
                off = rows(e.offsets_on(device))[sel]
                new = torch.sigmoid(torch.logit(c.clamp(1e-6, 1 - 1e-6)) + off)
            colors = colors.index_put((sel,), new)
        out["colors"] = colors
        return dataclasses.replace(canon, **out)

    def apply_posed(self, posed: PosedGaussians) -> PosedGaussians:
        """Erased Gaussians at opacity 0 (all Gaussians, in order)."""
        er = self.erased
        if er is None:
            return posed
        keep = torch.as_tensor(~er, device=posed.opacities.device)
        return dataclasses.replace(posed, opacities=posed.opacities * keep.to(posed.opacities.dtype))
