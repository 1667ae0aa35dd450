"""The daemon's configuration file (``swarmd run --config FILE``), checked field by field.

The documented default is ``config/swarmd.yaml``. Checking walks PyYAML's composed node tree
(the plain loaded dict has no line numbers), so every rejection is one line of the form
``FILE:LINE: field PATH: problem; fix: ...`` and the daemon stops with exit 78 (EX_CONFIG)
before it opens a socket. Relative paths are taken relative to the config file's folder.

This module is the entry every caller imports from; the modules behind it, by concern:
``model`` (the checked values, ``DaemonConfig`` and its sections, the trust checks on the
files it names), ``reader`` (the field readers and each section's known fields),
``checker`` (the whole file, section by section), ``px4`` (the ``px4:`` section) and
``services`` (``dataplane:`` and ``ros2:``).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from swarmd.config.checker import Checker
from swarmd.config.model import (
    DEFAULT_BUNDLE,
    DEFAULT_PX4_CONNECTION,
    DEFAULT_SOCKET,
    DEFAULT_STATE_DIR,
    LOG_FORMATS,
    LOG_LEVELS,
    MAX_POLL_S,
    MIN_POLL_S,
    BundleConfig,
    ConfigError,
    DaemonConfig,
    DataplaneSection,
    LinkConfig,
    Px4Section,
    Ros2Section,
    config_mode_problem,
    trust_problem,
)
from swarmd.config.reader import FIELDS as _FIELDS
from swarmd.yamldoc import composed, read_regular_text

__all__ = [
    "DEFAULT_BUNDLE",
    "DEFAULT_PX4_CONNECTION",
    "DEFAULT_SOCKET",
    "DEFAULT_STATE_DIR",
    "LOG_FORMATS",
    "LOG_LEVELS",
    "MAX_POLL_S",
    "MIN_POLL_S",
    "_FIELDS",
    "BundleConfig",
    "ConfigError",
    "DaemonConfig",
    "DataplaneSection",
    "LinkConfig",
    "Px4Section",
    "Ros2Section",
    "config_mode_problem",
    "load_config",
    "parse_config",
    "trust_problem",
]


def load_config(path: str | Path, *, engine_fields: frozenset[str] | None = None) -> DaemonConfig:
    """Read and check ``path``; raises ``ConfigError`` (one line) on any problem.

    ``engine_fields``: the names ``discovery.overrides`` may set (the engine config's
    fields); None skips that check.
    """
    file = str(path)
    text, read = read_regular_text(
        path, ConfigError, missing_fix="give the path of swarmd.yaml", what="config file"
    )
    config = parse_config(text, file, base=Path(path).parent, engine_fields=engine_fields)
    return replace(config, read_stat=read)  # judged by check_trusted_files: what was read


def parse_config(
    text: str,
    file: str = "<config>",
    *,
    base: Path | None = None,
    engine_fields: frozenset[str] | None = None,
) -> DaemonConfig:
    """Check a config given as YAML text; relative paths resolve against ``base``."""
    with composed(text, file, ConfigError, empty_fix="see config/swarmd.yaml") as (root, loader):
        return Checker(file, loader, base, engine_fields).config(root)
