"""Deprecated import path, kept so that plugins written for allorules 0.1 still load: use
``from allorules.plugins import hookimpl`` (docs/plugins.md)."""
import warnings

from allorules.plugins.hookspecs import hookimpl, hookspec  # noqa: F401

warnings.warn("'allorules.hookspecs' is deprecated: import hookimpl from 'allorules.plugins'",
              DeprecationWarning, stacklevel=2)
