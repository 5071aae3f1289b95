"""Shared fixtures: the paper's 'sport' damper."""

import pytest

from damper_emulator.model.compressible import DamperModel
from damper_emulator.params import load_config


@pytest.fixture(scope="session")
def sport_cfg():
    return load_config()


@pytest.fixture(scope="session")
def sport_model(sport_cfg):
    return DamperModel(sport_cfg)
