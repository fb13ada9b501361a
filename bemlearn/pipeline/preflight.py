"""Check the whole config and environment before any long step (seconds, nothing written).

Every CLI command that runs a long step (collect, train, run, simulate, walk, gpdm) calls
:func:`preflight` first: an empty or comment-only config, an unknown robot or missing MJCF
(or one whose physics makes no sense: ``timestep="0"``, NaN parameters), any value of any
section that is of the wrong type, not finite, out of its component's limits or inconsistent
with another (:func:`check_config`: the whole config is parsed and resolved), a missing or
unreadable data file, ``--device cuda`` without CUDA, an unwritable output folder, or outputs
that exist (without ``--force``) end the command within a second or two, before any folder
is created.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bemlearn.config import config_folder, load_yaml, rebase_paths
from bemlearn.errors import BemlearnError, ConfigError, EnvironmentProblem, MissingFileError
from bemlearn.files import check_outputs, check_writable

if TYPE_CHECKING:
    from bemlearn.pipeline.config import PipelineConfig
    from bemlearn.pipeline.resolve import ResolvedConfig

__all__ = ["preflight", "Preflight", "check_config_file", "check_config", "check_robot", "check_device", "check_data_file"]

log = logging.getLogger(__name__)

#: Top-level keys of which a config must name at least one (otherwise it is empty for our purpose).
REQUIRED_ANY = ("robot", "data")


@dataclass(frozen=True)
class Preflight:
    """What :func:`preflight` read, so that the command does not read and resolve the config again.

    Attributes:
        path: the config file (``None`` when the command has none).
        raw: its mapping as written (``{}`` without a config).
        resolved: the config as :func:`~bemlearn.pipeline.resolve.resolve_pipeline_config` resolved it
            (``None`` without a config and for an application's config).
    """

    path: str | os.PathLike[str] | None
    raw: dict[str, Any]
    resolved: ResolvedConfig | None

    def pipeline_config(self) -> PipelineConfig:
        """The resolved pipeline config (an application's config is parsed as one, and refused as before)."""
        if self.resolved is not None:
            return self.resolved.config
        from bemlearn.pipeline.resolve import load_pipeline_config

        if self.path is None:
            raise ConfigError("no config was checked")
        return load_pipeline_config(Path(self.path))


def check_config_file(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The config's mapping; empty, comment-only or robot-less configs are errors.

    Raises:
        ConfigError: the file is missing, not YAML, not a mapping, or names neither
            ``robot:`` nor ``data:`` (an empty config would silently run on hidden defaults).
    """
    from bemlearn.pipeline.config import PATH_KEYS

    data = rebase_paths(load_yaml(Path(path)), PATH_KEYS, config_folder(Path(path)))  # relative to the config's folder
    if not any(k in data for k in REQUIRED_ANY):
        what = "is empty (or only comments)" if not data else f"names neither {' nor '.join(f'{k}:' for k in REQUIRED_ANY)} (keys: {sorted(data)})"
        raise ConfigError(
            f"{path}: config {what}; expected at least 'robot: <name or MJCF path>' "
            "(`robot: path/to/robot.xml` alone is enough; docs/config.md)"
        )
    return data


def check_config(path: str | os.PathLike[str], data: dict[str, Any]) -> ResolvedConfig | None:
    """Parse every section of the config at ``path`` (read as ``data`` by :func:`check_config_file`) strictly, as the command will: an application's
    config by its application's parser, a pipeline config by
    :func:`~bemlearn.pipeline.resolve.resolve_pipeline_config` (types, finite numbers, limits, the
    rules between sections and those that need the robot, with the values derived from its model).

    Returns:
        the resolved pipeline config, for the command to use as it is (``None`` for an application's config).

    Raises:
        ConfigError: naming the file and the key.
    """
    if data.get("application") is not None:
        from bemlearn.applications import get_application

        try:
            app = get_application(str(data["application"]))
        except ConfigError as exc:
            raise ConfigError(f"{path}: application: {exc}") from None
        if app.parse_config is not None:
            app.parse_config(path)
        return None
    from bemlearn.pipeline.resolve import resolve_pipeline_config

    return resolve_pipeline_config(data, source=str(path))   # ``data``: read once, its paths already relative to its folder


def check_robot(name: Any, *, where: str = "robot", coordinates: Any = None) -> None:
    """Load the robot named ``name`` (registry name or MJCF path; ``coordinates``: the config's ``coordinates:``
    block, a mapping); errors name ``where``.

    Raises:
        ConfigError: not a string, an unknown name, or a missing / unreadable MJCF file.
    """
    from bemlearn.robots import load, registered_robots

    known = sorted(registered_robots())
    if not isinstance(name, str) or not name:
        raise ConfigError(f"{where}: expected a robot name {known} or an MJCF path, got {name!r}")
    if name not in known:
        path = Path(name)
        if path.suffix.lower() != ".xml" and not path.exists():
            raise ConfigError(f"{where}: unknown robot {name!r}; registered robots are {known}, or give the path of an MJCF (.xml) file")
        if not path.is_file():
            raise ConfigError(f"{where}: MJCF file {name} not found")
    try:
        load(name, coordinates=coordinates if isinstance(coordinates, dict) else None)
    except (BemlearnError, OSError) as exc:
        raise ConfigError(f"{where}: cannot load robot {name!r}: {exc}") from exc


def check_device(device: str | None, *, where: str = "--device") -> None:
    """``cuda`` needs a CUDA device.

    Raises:
        EnvironmentProblem: CUDA was asked for and ``torch.cuda.is_available()`` is false.
    """
    if device and str(device).startswith("cuda"):
        import torch

        if not torch.cuda.is_available():
            raise EnvironmentProblem(f"{where} {device}: CUDA was requested but no CUDA device is available (use --device cpu)")


def check_data_file(path: str | os.PathLike[str], *, robot: str | None = None, where: str = "--data") -> None:
    """The trajectory file exists and reads (its joints match ``robot`` when given).

    Raises:
        MissingFileError: (a FileNotFoundError) no such file.
        TrajectoryFormatError: the file is not a valid trajectory file.
    """
    from bemlearn.data import read_trajectory

    path = Path(path)
    if not path.is_file():
        raise MissingFileError(f"{where}: trajectory file {path} not found")
    read_trajectory(path, robot=robot)


def preflight(
    *,
    config: str | os.PathLike[str] | None = None,
    robot: bool = True,
    device: str | None = None,
    data: str | os.PathLike[str] | None = None,
    outputs: Iterable[str | os.PathLike[str]] = (),
    out_dir: str | os.PathLike[str] | None = None,
    force: bool = False,
) -> Preflight:
    """Run every check that applies; returns the config as read and as resolved (:class:`Preflight`).

    Args:
        config: the YAML file (see :func:`check_config_file`); its ``robot`` is loaded when
            ``robot`` is true, its ``train.device`` checked when ``device`` is ``None``.
        device: the ``--device`` option.
        data: a trajectory file that must exist and read for the config's robot.
        outputs: files (or folders) the command would write; existing ones need ``force``.
        out_dir: the folder the command writes into; it must be writable.
        force: allow replacing ``outputs``.
    """
    # cheap checks first: a wrong device or an existing output is reported before the robot is loaded
    # and the config resolved (the derivation runs trials in MuJoCo: seconds)
    cfg: dict[str, Any] = {}
    resolved = None
    if config is not None:
        cfg = check_config_file(config)
        train = cfg.get("train")
        if device is None and isinstance(train, dict):
            check_device(train.get("device"), where=f"{config}: train.device")
    check_device(device)
    if out_dir is not None:
        check_writable(out_dir)
    check_outputs(outputs, force)
    if data is not None:  # the file must read; its joints are checked against the robot by the command itself
        check_data_file(data)
    if config is not None:
        if robot and "robot" in cfg:
            check_robot(cfg["robot"], where=f"{config}: robot", coordinates=cfg.get("coordinates"))
        resolved = check_config(config, cfg)
    log.debug("preflight passed")
    return Preflight(config, cfg, resolved)
