"""The numerical-stability and reliability suite (docs/stability.md): every test here carries the
``stability`` marker (``pytest -m stability`` runs the suite alone; plain ``pytest -q`` runs it with
the rest). The fixtures of tests/conftest.py apply here too."""

from pathlib import Path

import pytest
import torch

STABILITY_DIR = Path(__file__).parent


def pytest_configure(config):
    config.addinivalue_line("markers", "stability: numerical-stability and reliability suite (docs/stability.md)")


def pytest_collection_modifyitems(config, items):
    for item in items:
        if STABILITY_DIR in item.path.parents:
            item.add_marker(pytest.mark.stability)


@pytest.fixture(scope="session")
def tiny_avatar_config():
    from reconstruct.avatar.config import AvatarConfig

    return AvatarConfig(gaussian_resolution=48, feature_resolution=32, feature_channels=8, pose_feature_channels=8,
                        hidden=32)


@pytest.fixture(scope="session")
def tiny_avatar(anny_body, tiny_avatar_config):
    """A small avatar (about 1.4k Gaussians) on the default test body."""
    from reconstruct.avatar.model import AvatarModel

    torch.manual_seed(0)
    return AvatarModel(anny_body, tiny_avatar_config)
