"""Applications: robot-specific packages built on the core, discovered as plugins.

The core (robots from MJCF, data, models, fitting, export, control, simulation, the pipeline
stages and the CLI) knows no robot by name.  Robot-specific work (a motor model, a walking
controller, a study, a report) lives in an *application*: a package that imports the core and
declares itself under the entry-point group ``bemlearn.applications`` of its distribution::

    [project.entry-points."bemlearn.applications"]
    myrobot = "mypackage.myrobot:APPLICATION"

where ``APPLICATION`` is an :class:`Application`.  The core loads the declared applications
lazily, the first time a robot name, an application name or the CLI needs them, so nothing in
the core imports an application module by name.  bemlearn's own Furuta and biped applications
are declared the same way in its ``pyproject.toml``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

from bemlearn.errors import ArgumentError, ConfigError
from bemlearn.warnings import EnvironmentWarning, warn

__all__ = ["Application", "ENTRY_POINT_GROUP", "applications", "get_application", "register_application"]

log = logging.getLogger(__name__)

#: The entry-point group applications are declared under.
ENTRY_POINT_GROUP = "bemlearn.applications"


@dataclass(frozen=True)
class Application:
    """What an application contributes to the core.

    Attributes:
        name: the application's name (the ``application:`` key of its configs).
        description: one line for ``bemlearn --help`` and error messages.
        robots: registry names → factories returning a :class:`~bemlearn.robots.Robot`
            (e.g. ``"furuta": lambda: MujocoRobot.from_xml(path, name="furuta")``).
        add_cli: ``add_cli(subparsers)`` registers the application's top-level commands.
        add_bench: ``add_bench(subparsers)`` registers its ``bemlearn bench`` commands.
        add_robot_commands: ``add_robot_commands(subparsers)`` registers ``bemlearn robot`` commands.
        run: ``run(config_path, out_dir, *, device, progress) -> Path`` runs a config whose
            top-level ``application:`` key names this application (``bemlearn run``).
        parse_config: ``parse_config(config_path)`` parses and validates such a config strictly
            (raising :class:`~bemlearn.errors.ConfigError`); the preflight of every command calls it.
        sweep_stages: stage name → a factory returning a :class:`~bemlearn.sweep.stage.SweepStage`
            that ``bemlearn sweep`` runs for configs naming this application (``stage:`` of a sweep file).
    """

    name: str
    description: str
    robots: dict[str, Callable[[], Any]] = field(default_factory=dict)
    add_cli: Callable[[Any], None] | None = None
    add_bench: Callable[[Any], None] | None = None
    add_robot_commands: Callable[[Any], None] | None = None
    run: Callable[..., Path] | None = None
    parse_config: Callable[[Any], Any] | None = None
    sweep_stages: dict[str, Callable[[], Any]] = field(default_factory=dict)


_APPS: dict[str, Application] = {}
_LOADED = False


def register_application(app: Application) -> None:
    """Add ``app`` (normally done by discovery; tests and scripts may call it directly)."""
    if not isinstance(app, Application):
        raise ArgumentError(f"register_application: expected an Application, got {type(app).__name__}")
    _APPS[app.name] = app


def _discover() -> None:
    global _LOADED
    if _LOADED:
        return
    _LOADED = True
    for ep in metadata.entry_points(group=ENTRY_POINT_GROUP):
        try:
            app = ep.load()
        except Exception as exc:  # noqa: BLE001 - a broken plugin must not break the core
            warn(EnvironmentWarning, log, "application %r (%s) failed to load: %s", ep.name, ep.value, exc)
            continue
        if not isinstance(app, Application):
            warn(EnvironmentWarning, log, "entry point %r (%s) is not a bemlearn Application; ignored", ep.name, ep.value)
            continue
        register_application(app)


def applications() -> dict[str, Application]:
    """All applications: those registered directly and those declared as entry points."""
    _discover()
    return dict(_APPS)


def get_application(name: str) -> Application:
    """The application called ``name``; the error lists the installed ones."""
    apps = applications()
    if name not in apps:
        raise ConfigError(f"unknown application {name!r}; installed applications: {sorted(apps) or 'none'}")
    return apps[name]
