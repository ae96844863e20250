"""The fixtures the tests share (the bundled benchmark's config and scene, an asymmetric
tumbling body). What they share that is not a fixture is in helpers.py."""

import pytest
import yaml
from helpers import CONFIGS

from rbstudy.inputs.scenes import scene_from_mapping


@pytest.fixture(scope="session")
def abaqus_config():
    """The bundled benchmark config, as users run it."""
    return yaml.safe_load((CONFIGS / "abaqus_top.yaml").read_text())


@pytest.fixture(scope="session")
def abaqus_scene(abaqus_config):
    return scene_from_mapping(abaqus_config["scene"], source="configs/abaqus_top.yaml")


@pytest.fixture(scope="session")
def asymmetric_scene():
    """I = (1, 2, 3) tumbling about no principal axis, from a general orientation."""
    return scene_from_mapping(
        {
            "body": {"inertia": [1.0, 2.0, 3.0]},
            "initial": {
                "angular_velocity": {"body": [0.6, 1.5, 0.9]},
                "orientation": {"rotation_vector": [0.3, -0.2, 0.5]},
            },
            "duration": 4.0,
        },
        source="test",
    )
