"""Controllers: the EIC law (eq. 3, 8), BEM sources, the inverse of MuJoCo's actuator model, LQR."""

from typing import TYPE_CHECKING

from bemlearn._lazy import lazy_namespace

if TYPE_CHECKING:  # imported on first use: bemlearn._lazy
    from bemlearn.control.actuator_inverse import MujocoActuatorInverse
    from bemlearn.control.bem_sources import BEM_SOURCES, BEMSource, ModelBEM, PredictorBEM, ZeroBEM, make_bem_source
    from bemlearn.control.eic import Actuator, EICController, EICGains
    from bemlearn.control.lqr import LQRResult, discrete_lqr, linearize

__all__ = [
    "Actuator",
    "BEM_SOURCES",
    "BEMSource",
    "EICController",
    "EICGains",
    "LQRResult",
    "ModelBEM",
    "MujocoActuatorInverse",
    "PredictorBEM",
    "ZeroBEM",
    "discrete_lqr",
    "linearize",
    "make_bem_source",
]

__getattr__, __dir__ = lazy_namespace(__name__, __file__)
