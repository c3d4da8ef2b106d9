from .config import AvatarConfig
from .model import AvatarModel, CanonicalGaussians, PosedGaussians

__all__ = ["AvatarConfig", "AvatarModel", "CanonicalGaussians", "PosedGaussians"]
