"""Plugins: the hooks a plugin implements, what it returns, and the registry that gathers them."""
from allorules.plugins.hookspecs import hookimpl
from allorules.plugins.registry import PluginRegistry, registry_for
from allorules.plugins.specs import (
           ConstraintContext,
           ConstraintSpec,
           MeasureSpec,
           ParameterSpec,
           SegmenterSpec,
)

__all__ = ["hookimpl", "PluginRegistry", "registry_for", "MeasureSpec", "SegmenterSpec", "ConstraintSpec",
           "ParameterSpec", "ConstraintContext"]
