"""Fixtures shared by the controller tests."""
from __future__ import annotations

import pytest

from ciml_control.references import standing_configuration
from ciml_learning.core.robot import load_robot


@pytest.fixture(scope="module")
def robot():
    return load_robot()


@pytest.fixture(scope="module")
def q_stand(robot):
    """The standing pose with the feet 2 cm above the ground plane (foot frames at sphere centres)."""
    return standing_configuration(robot, 0.02)
