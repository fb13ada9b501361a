"""bemlearn's own applications, built on the core's public stages.

* :mod:`bemlearn.apps.furuta` — the Quanser rotary pendulum of the paper's Section IV-A: its
  MJCF and analytic models, the paper-row variant, the motor model and its studies.
* :mod:`bemlearn.apps.biped` — the 5-link planar biped of Section IV-B: gaits, the walking
  controller, human gait, the torso-BEM and GPDM pipeline and its report.
* :mod:`bemlearn.apps.bikebot` — an autonomous bicycle (steer and rear wheel driven, roll free): its
  MJCF and its model roll BEM from the hard rolling constraint, checked against the steady-turn balance.

Each declares itself as a plugin (``bemlearn.applications`` entry point, see
:mod:`bemlearn.applications`); the core never imports them by name.
"""

__all__: list[str] = []
