"""Effects outside the diagnosis' catalogue: the simulator has them so that tests can check the
diagnosis says "unexplained" (localised) instead of naming a wrong effect. Fields and wording only."""
from __future__ import annotations

from ciml_learning.effects.base import EffectType, Field


class JointSpring(EffectType):
    name = "joint_spring"
    fields = {"joint": Field("joints"), "stiffness": Field("float", "Nm/rad", 0.0, 1000.0),
              "rest": Field("float", "rad", -3.2, 3.2)}
    in_catalogue = False
    wording = "a spring at the joint, −stiffness (q − rest)"


class TorqueRipple(EffectType):
    name = "torque_ripple"
    fields = {"joint": Field("joints"), "amplitude": Field("float", "Nm", 0.0, 50.0),
              "period": Field("float", "rad", 0.01, 6.3)}
    in_catalogue = False
    wording = "a joint torque amplitude sin(2π q/period)"


class TorqueSensorRipple(EffectType):
    name = "torque_sensor_ripple"
    fields = {"joint": Field("joints"), "amplitude": Field("float", "Nm", 0.0, 50.0),
              "period": Field("float", "rad", 0.01, 6.3)}
    kind = "sensor"
    measurement_only = True
    in_catalogue = False
    wording = "a torque-reading error amplitude sin(2π q/period), the joint's torque unchanged"


EFFECTS = (JointSpring(), TorqueRipple(), TorqueSensorRipple())
