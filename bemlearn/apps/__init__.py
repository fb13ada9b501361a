"""bemlearn's own applications, built on the core's public stages.

* :mod:`bemlearn.apps.furuta` — the Quanser rotary pendulum of the paper's Section IV-A: its
  MJCF and analytic models, the paper-row variant, the motor model and its studies.
* :mod:`bemlearn.apps.biped` — the 5-link planar biped of Section IV-B: gaits, the walking
  controller, human gait, the torso-BEM and GPDM pipeline and its report.

Each declares itself as a plugin (``bemlearn.applications`` entry point, see
:mod:`bemlearn.applications`); the core never imports them by name.
"""

__all__: list[str] = []
