"""Parameter schemas of the ciml_control nodes (ciml_learning.params): each is the one source
of the node's declare() calls, its config/<node>.yaml and its README table."""
from __future__ import annotations

from ciml_learning.params import NodeSchema, Param

from .references import MOTIONS

URDF = Param("urdf", "", "Robot URDF ('' = HyQ from example-robot-data)")

REFERENCE_GENERATOR = NodeSchema("ciml_control", "reference_generator", "the full-body reference of a motion on /reference", (
    Param("motion", "stand", "Motion to generate", choices=MOTIONS, deploy="trot_35"),
    Param("rate", 250.0, "Publish rate", "Hz", 1.0, 1000.0, read_only=False),
    Param("foot_height", 0.002, "Height of the foot frames above the ground when standing (sphere foot radius "
          "of the simulation)", "m", 0.0, 0.2),
    URDF,
))

SCHEMAS: tuple[NodeSchema, ...] = (REFERENCE_GENERATOR,)
