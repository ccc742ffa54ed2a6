"""Deprecated import path, kept so that plugins written for allorules 0.1 still load: use
``from allorules.plugins import MeasureSpec, ConstraintSpec, ...`` (docs/plugins.md)."""
import warnings

from allorules.plugins.specs import (  # noqa: F401
    ConstraintContext,
    ConstraintSpec,
    MeasureSpec,
    ParameterSpec,
    SegmenterSpec,
)

warnings.warn("'allorules.specs' is deprecated: import the spec classes from 'allorules.plugins'",
              DeprecationWarning, stacklevel=2)
