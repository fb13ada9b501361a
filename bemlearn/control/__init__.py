"""Controllers: the EIC law (eq. 3, 8), BEM sources, actuator maps."""

from bemlearn.control.actuators import ActuatorModel, DirectTorque, FurutaMotor
from bemlearn.control.bem_sources import BEM_SOURCES, ModelBEM, PredictorBEM, ZeroBEM, make_bem_source
from bemlearn.control.eic import EICController, EICGains

__all__ = [
    "ActuatorModel",
    "BEM_SOURCES",
    "DirectTorque",
    "EICController",
    "EICGains",
    "FurutaMotor",
    "ModelBEM",
    "PredictorBEM",
    "ZeroBEM",
    "make_bem_source",
]
