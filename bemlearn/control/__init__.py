"""Controllers: the EIC law (eq. 3, 8), BEM sources, actuator maps, biped gaits and walking."""

from bemlearn.control.actuators import ActuatorModel, DirectTorque, FurutaMotor
from bemlearn.control.bem_sources import BEM_SOURCES, ModelBEM, PredictorBEM, ZeroBEM, make_bem_source
from bemlearn.control.eic import EICController, EICGains
from bemlearn.control.gait import BezierGait, GaitConfig, build_gait
from bemlearn.control.walking import WalkExcitation, WalkingController, WalkingGains

__all__ = [
    "ActuatorModel",
    "BEM_SOURCES",
    "BezierGait",
    "DirectTorque",
    "EICController",
    "EICGains",
    "FurutaMotor",
    "GaitConfig",
    "ModelBEM",
    "PredictorBEM",
    "WalkExcitation",
    "WalkingController",
    "WalkingGains",
    "ZeroBEM",
    "build_gait",
    "make_bem_source",
]
