"""Plugin discovery and the registry of everything plugins provide.

Plugins come from three places, in this order: the built-ins
(:mod:`allorules.plugins.builtin`, name ``builtin``), installed packages declaring an entry point
in the group ``allorules``, and explicit paths (``--plugin PATH`` on the command line or
``plugins:`` in a ruleset), each a ``.py`` file or a package folder. Nothing is ever loaded from
the current folder unless named. A plugin that fails to import, whose hook raises, exits or
returns something malformed, or whose hook names allorules would never call, is recorded in
:attr:`PluginRegistry.failures`, reported by name on stderr, and the rest keep working.

A third-party plugin's measures, segmenters and constraints are :func:`contained`: whatever they
raise, return wrongly or exit with during a run ends in one :class:`~allorules.errors.PluginError`
line that names the plugin and what it did.

:class:`PluginRegistry` is a :class:`pluggy.PluginManager` that also gathers what the hooks
return: :meth:`~PluginRegistry.measures`, :meth:`~PluginRegistry.segmenters`,
:meth:`~PluginRegistry.constraints`, :meth:`~PluginRegistry.ruleset_paths` and
:meth:`~PluginRegistry.describe`.
"""
from __future__ import annotations

import argparse
import difflib
import functools
import importlib
import importlib.metadata
import importlib.util
import logging
import math
import sys
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping

import numpy as np
import pluggy

from allorules.errors import AllorulesError, PluginError
from allorules.plugins import hookspecs
from allorules.plugins.specs import (
    MEASURE_KINDS,
    ConstraintSpec,
    MeasureSpec,
    SegmenterSpec,
)

log = logging.getLogger("allorules")

ENTRY_POINT_GROUP = "allorules"
ORIGIN_BUILTIN = "built-in"
ORIGIN_ENTRY_POINT = "entry point"
ORIGIN_PATH = "path"

# hook name -> (kind shown to users, spec class every item must be)
PROVIDED_KINDS: dict[str, tuple[str, type]] = {
    "allorules_measures": ("measure", MeasureSpec),
    "allorules_segmenters": ("segmenter", SegmenterSpec),
    "allorules_constraints": ("constraint", ConstraintSpec),
    "allorules_ruleset_paths": ("ruleset path", Path),
}


@dataclass
class PluginFailure:
    """A plugin (or one of its hooks) that did not work, in one line for the user."""

    plugin: str
    origin: str
    message: str

    def __str__(self) -> str:
        return f"plugin {self.plugin!r} ({self.origin}): {self.message}"


@dataclass
class PluginInfo:
    """What ``allorules plugins`` shows for one plugin."""

    name: str
    origin: str            # "built-in", "entry point", "path"
    location: str          # module file, or entry point "name = module"
    provides: dict[str, list[str]] = field(default_factory=dict)   # kind -> names
    failed: list[str] = field(default_factory=list)                # failure messages


class PluginRegistry(pluggy.PluginManager):
    """A pluggy plugin manager that knows where each plugin came from and what it provides."""

    def __init__(self) -> None:
        super().__init__(hookspecs.PROJECT_NAME)
        self.add_hookspecs(hookspecs)
        self.origins: dict[str, tuple[str, str]] = {}   # plugin name -> (origin, location)
        self.failures: list[PluginFailure] = []
        self._reported: set[tuple[str, str]] = set()
        self._gathered: dict[str, dict[str, Any]] | None = None

    # -- loading -----------------------------------------------------------------------------
    def add_plugin(self, module: Any, name: str, origin: str, location: str = "") -> bool:
        """Register ``module`` under ``name``; record a failure instead of raising."""
        if self.has_plugin(name) or self.is_registered(module):
            return False
        try:
            self.register(module, name=name)
        except Exception as error:  # pluggy validation: wrong hook signatures, unknown hooks
            self._fail(name, origin, f"could not be registered: {_one_line(error)}")
            return False
        self.origins[name] = (origin, location or str(getattr(module, "__file__", "") or ""))
        self._gathered = None
        if origin != ORIGIN_BUILTIN:
            self._check_hook_names(module, name, origin)
        return True

    def _check_hook_names(self, module: Any, name: str, origin: str) -> None:
        """Warn about a plugin whose hooks allorules will never call: names that are not hooks (a
        typo such as ``allorules_constraint``) or hook functions without ``@hookimpl``."""
        hooks = set(PROVIDED_KINDS)
        registered = {caller.name for caller in (self.get_hookcallers(module) or [])}
        for attribute in sorted(dir(module)):
            if not attribute.startswith("allorules_") or not callable(getattr(module, attribute, None)):
                continue
            if attribute not in hooks:
                close = difflib.get_close_matches(attribute, sorted(hooks), n=1)
                hint = f"; did you mean {close[0]}?" if close else f"; the hooks are {', '.join(sorted(hooks))}"
                self._fail(name, origin, f"{attribute} is not an allorules hook and is never called{hint}")
            elif attribute not in registered:
                self._fail(name, origin, f"{attribute} is not marked @hookimpl (from allorules.plugins import hookimpl), "
                           "so it is never called")
        if not registered & hooks:
            self._fail(name, origin, "implements none of the hooks " + ", ".join(sorted(hooks))
                       + "; it provides nothing (docs/plugins.md)")

    def load_builtins(self) -> None:
        from allorules.plugins import builtin

        self.add_plugin(builtin, "builtin", ORIGIN_BUILTIN, builtin.__file__)

    def load_entry_points(self) -> None:
        """Load every installed plugin declared in the entry-point group ``allorules``."""
        try:
            entry_points = importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)
        except Exception as error:  # broken metadata of some installed distribution
            self._fail("<entry points>", ORIGIN_ENTRY_POINT, f"could not be listed: {_one_line(error)}")
            return
        seen: set[str] = set()
        for entry_point in sorted(entry_points, key=lambda item: item.name):
            if entry_point.name in seen:   # the same distribution visible twice on sys.path
                continue
            seen.add(entry_point.name)
            location = f"{entry_point.name} = {entry_point.value}"
            if self.has_plugin(entry_point.name):
                continue
            try:
                module = entry_point.load()
            except Exception as error:
                self._fail(entry_point.name, ORIGIN_ENTRY_POINT, f"failed to import: {_one_line(error)}")
                continue
            self.add_plugin(module, entry_point.name, ORIGIN_ENTRY_POINT, location)

    def load_path(self, path: str | Path) -> str | None:
        """Load a plugin from a ``.py`` file, a package folder or a plugin project folder.

        A project folder (no ``__init__.py``, but a ``pyproject.toml`` declaring
        ``[project.entry-points.allorules]``) loads the modules its entry points name, from
        that folder. Returns the plugin's name (the last one for a project), None on failure.
        Loading the same module twice (say from ``--plugin`` and from a ruleset, or a path to
        a module that is also installed) registers it once.
        """
        path = Path(path).expanduser()
        name = path.stem if path.suffix == ".py" else path.name
        if not path.exists():
            self._fail(name, ORIGIN_PATH, f"{path} does not exist; give the path of a .py file or a package folder")
            return None
        if path.is_dir() and not (path / "__init__.py").is_file():
            if (path / "pyproject.toml").is_file():
                return self._load_project(path)
            self._fail(name, ORIGIN_PATH, f"{path} is a folder without __init__.py or pyproject.toml; "
                       "give a .py file, a package folder or a plugin project folder")
            return None
        if path.is_dir():
            module_file = (path / "__init__.py").resolve()
        elif path.suffix != ".py":
            self._fail(name, ORIGIN_PATH, f"{path} is not a .py file; give a .py file or a package folder")
            return None
        else:
            module_file = path.resolve()
        module_name = f"allorules_plugin_{name.replace('-', '_').replace('.', '_')}"
        for plugin_name, module in self.list_name_plugin():
            registered_file = getattr(module, "__file__", None)
            if registered_file and Path(registered_file).resolve() == module_file:
                return plugin_name
            if getattr(module, "__name__", None) in (name, module_name):   # the same module, installed
                origin, location = self.origins.get(plugin_name, ("?", ""))
                if origin == ORIGIN_ENTRY_POINT and registered_file:
                    log.warning("plugin %s: %s is also installed (entry point %r, from %s); the installed copy is "
                                "used: uninstall it (pip uninstall) to load the file instead", name, path, plugin_name,
                                registered_file)
                return plugin_name
        if self.has_plugin(name):
            self._fail(name, ORIGIN_PATH, f"{path}: another plugin is already registered as {name!r}; rename the file")
            return None
        try:
            spec = importlib.util.spec_from_file_location(
                module_name, module_file,
                submodule_search_locations=[str(module_file.parent)] if path.is_dir() else None,
            )
            if spec is None or spec.loader is None:
                raise ImportError(f"cannot import {module_file}")
            module = importlib.util.module_from_spec(spec)
            sys.modules[module_name] = module
            spec.loader.exec_module(module)
        except BaseException as error:  # SystemExit/KeyboardInterrupt in a plugin's import too
            sys.modules.pop(module_name, None)
            if isinstance(error, KeyboardInterrupt):
                raise
            self._fail(name, ORIGIN_PATH, f"failed to import {path}: {type(error).__name__}: {_one_line(error)}")
            return None
        return name if self.add_plugin(module, name, ORIGIN_PATH, str(module_file)) else None

    def _load_project(self, folder: Path) -> str | None:
        """Load the modules a plugin project's pyproject.toml declares as allorules entry points."""
        name = folder.name
        try:
            import tomllib
        except ImportError:  # Python 3.10
            self._fail(name, ORIGIN_PATH, f"{folder}: reading pyproject.toml needs Python 3.11; give the .py file instead")
            return None
        try:
            project = tomllib.loads((folder / "pyproject.toml").read_text(encoding="utf-8"))
            declared = project["project"]["entry-points"][ENTRY_POINT_GROUP]
        except (KeyError, TypeError):
            self._fail(name, ORIGIN_PATH, f"{folder}/pyproject.toml declares no [project.entry-points.allorules]; "
                       "give the plugin's .py file instead")
            return None
        except Exception as error:
            self._fail(name, ORIGIN_PATH, f"{folder}/pyproject.toml cannot be read: {_one_line(error)}")
            return None
        loaded = None
        for value in declared.values():
            module = str(value).split(":")[0].strip()
            relative = Path(*module.split("."))
            for candidate in (folder / relative.with_suffix(".py"), folder / relative,
                              folder / "src" / relative.with_suffix(".py"), folder / "src" / relative):
                if candidate.is_file() or (candidate / "__init__.py").is_file():
                    loaded = self.load_path(candidate) or loaded
                    break
            else:
                self._fail(name, ORIGIN_PATH, f"{folder}: entry point module {module!r} not found in the folder")
        return loaded

    def load_paths(self, paths: Iterable[str | Path]) -> None:
        for path in paths:
            self.load_path(path)

    # -- what plugins provide -----------------------------------------------------------------
    def _gather(self) -> dict[str, dict[str, Any]]:
        """Call every hook of every plugin separately; a failing one is recorded and skipped."""
        if self._gathered is not None:
            return self._gathered
        gathered: dict[str, dict[str, Any]] = {hook: {} for hook in PROVIDED_KINDS}
        providers: dict[str, dict[str, str]] = {hook: {} for hook in PROVIDED_KINDS}
        self._provided: dict[str, dict[str, list[str]]] = {}
        order = [name for name, _ in self.list_name_plugin()]
        for hook_name, (kind, spec_class) in PROVIDED_KINDS.items():
            implementations = {impl.plugin_name: impl for impl in getattr(self.hook, hook_name).get_hookimpls()}
            for plugin_name in order:   # registration order: built-ins first, so they win clashes
                implementation = implementations.get(plugin_name)
                if implementation is None:
                    continue
                origin = self.origins.get(plugin_name, ("?", ""))[0]
                try:
                    items = implementation.function()
                except KeyboardInterrupt:
                    raise
                except SystemExit as error:
                    self._fail(plugin_name, origin, f"hook {hook_name} called sys.exit({error.code!r}); a plugin must "
                               "return its list (or raise an error), never exit")
                    continue
                except BaseException as error:
                    self._fail(plugin_name, origin, f"hook {hook_name} raised {type(error).__name__}: {_one_line(error)}")
                    continue
                if items is None:
                    items = []
                if not isinstance(items, (list, tuple)):
                    self._fail(plugin_name, origin, f"hook {hook_name} returned {type(items).__name__}; it must return a list of {spec_class.__name__}")
                    continue
                for item in items:
                    if spec_class is Path and isinstance(item, str):
                        item = Path(item)
                    if not isinstance(item, spec_class):
                        self._fail(plugin_name, origin, f"hook {hook_name} returned a {type(item).__name__}; expected {spec_class.__name__}")
                        continue
                    if spec_class is Path:
                        gathered[hook_name][str(item)] = item
                        self._provided.setdefault(plugin_name, {}).setdefault(kind, []).append(str(item))
                        continue
                    problem = _check_spec(item)
                    if problem:
                        self._fail(plugin_name, origin, f"{kind} {getattr(item, 'name', '?')!r}: {problem}")
                        continue
                    if item.name in gathered[hook_name]:
                        self._fail(plugin_name, origin, f"{kind} {item.name!r} is already provided by plugin "
                                   f"{providers[hook_name][item.name]!r}; this one is ignored (rename it)")
                        continue
                    if plugin_name != "builtin":
                        item = contained(item, plugin_name)
                    gathered[hook_name][item.name] = item
                    providers[hook_name][item.name] = plugin_name
                    self._provided.setdefault(plugin_name, {}).setdefault(kind, []).append(item.name)
        self._gathered = gathered
        self._providers = providers
        return gathered

    def measures(self) -> dict[str, MeasureSpec]:
        return dict(self._gather()["allorules_measures"])

    def segmenters(self) -> dict[str, SegmenterSpec]:
        return dict(self._gather()["allorules_segmenters"])

    def constraints(self) -> dict[str, ConstraintSpec]:
        return dict(self._gather()["allorules_constraints"])

    def ruleset_paths(self) -> list[Path]:
        return list(self._gather()["allorules_ruleset_paths"].values())

    def provider(self, kind: str, name: str) -> str | None:
        """Name of the plugin providing the ``kind`` (measure/segmenter/constraint) ``name``."""
        self._gather()
        hook = {"measure": "allorules_measures", "segmenter": "allorules_segmenters",
                "constraint": "allorules_constraints"}[kind]
        return self._providers[hook].get(name)

    def measure(self, name: str) -> MeasureSpec:
        return _lookup(self.measures(), name, "measure")

    def segmenter(self, name: str) -> SegmenterSpec:
        return _lookup(self.segmenters(), name, "segmenter")

    def constraint(self, name: str) -> ConstraintSpec:
        return _lookup(self.constraints(), name, "constraint")

    def describe(self) -> list[PluginInfo]:
        """Every plugin (and every plugin that failed to load): origin, location, what it provides."""
        self._gather()
        infos: dict[str, PluginInfo] = {}
        for name, _module in self.list_name_plugin():
            origin, location = self.origins.get(name, ("?", ""))
            infos[name] = PluginInfo(name, origin, location, dict(self._provided.get(name, {})))
        for failure in self.failures:
            info = infos.setdefault(failure.plugin, PluginInfo(failure.plugin, failure.origin, ""))
            info.failed.append(failure.message)
        return list(infos.values())

    # -- failures ----------------------------------------------------------------------------
    def _fail(self, plugin: str, origin: str, message: str) -> None:
        failure = PluginFailure(plugin, origin, message)
        if (plugin, message) in self._reported:
            return
        self._reported.add((plugin, message))
        self.failures.append(failure)
        log.warning("warning: %s", failure)


def _check_spec(item: Any) -> str | None:
    """What is malformed in a spec a plugin returned (None when it is usable)."""
    name = getattr(item, "name", None)
    if not isinstance(name, str) or not name.strip() or name != name.strip():
        return "its name must be non-empty text without surrounding spaces"
    if isinstance(item, MeasureSpec):
        if not callable(item.compute):
            return "compute is not callable"
        if item.kind not in MEASURE_KINDS:
            return f"kind {item.kind!r} is not one of {', '.join(MEASURE_KINDS)}"
        if isinstance(item.isometric_exponent, bool) or not isinstance(item.isometric_exponent, (int, float)):
            return "isometric_exponent must be a number"
    if isinstance(item, SegmenterSpec):
        if not callable(item.segment):
            return "segment is not callable"
        if not hasattr(item.parameters, "items"):
            return "parameters must be a mapping of name to default or ParameterSpec"
    if isinstance(item, ConstraintSpec):
        if not callable(item.residuals):
            return "residuals is not callable"
        if not hasattr(item.parameters, "items"):
            return "parameters must be a mapping of name to default or ParameterSpec"
    return None


# ---------------------------------------------------------------------------------------------
# Plugin code contained: what it raises, returns or exits with becomes one line naming it


def contained(spec: MeasureSpec | SegmenterSpec | ConstraintSpec, plugin: str):
    """The same spec with its callable wrapped by :func:`_guarded` (a third-party plugin's)."""
    if isinstance(spec, MeasureSpec):
        return replace(spec, compute=_guarded(spec.compute, plugin, f"measure {spec.name!r}", _positive_number))
    if isinstance(spec, SegmenterSpec):
        return replace(spec, segment=_guarded(spec.segment, plugin, f"segmenter {spec.name!r}", _labelled_body))
    return replace(spec, residuals=_guarded(spec.residuals, plugin, f"constraint {spec.name!r}", _residuals))


def _guarded(function: Callable, plugin: str, what: str, check: Callable[[Any, tuple], str | None]) -> Callable:
    """``function`` whose failures are one line naming the plugin: an allorules error it raises
    keeps its kind and message; any other exception, ``sys.exit`` or a result ``check`` refuses
    becomes a :class:`PluginError` that says what the plugin did."""

    @functools.wraps(function)
    def call(*args: Any, **kwargs: Any) -> Any:
        try:
            result = function(*args, **kwargs)
        except KeyboardInterrupt:
            raise
        except AllorulesError as error:   # the plugin's own clear error: its kind kept, the plugin named
            if not str(error).startswith(f"plugin {plugin!r}"):
                error.args = (f"plugin {plugin!r}, {what}: {error}",)
            raise
        except SystemExit as error:
            raise PluginError(f"plugin {plugin!r}, {what}, called sys.exit({error.code!r}); a plugin must raise "
                              "an error instead (docs/plugins.md)") from None
        except BaseException as error:
            raise PluginError(f"plugin {plugin!r}, {what}, failed with {type(error).__name__}: {_one_line(error)} "
                              "(a bug in the plugin: tell its author; --debug shows where)") from error
        problem = check(result, args)
        if problem:
            raise PluginError(f"plugin {plugin!r}, {what}, returned {problem}")
        return result

    return call


def _positive_number(value: Any, args: tuple) -> str | None:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        return f"a {type(value).__name__}; a measure returns one positive number"
    if not (math.isfinite(float(value)) and value > 0):
        return f"{float(value):g}; a measure must be a positive, finite number"
    return None


def _residuals(value: Any, args: tuple) -> str | None:
    if not isinstance(value, Mapping):
        return f"a {type(value).__name__}; a constraint returns a mapping of name to relative residual"
    for key, residual in value.items():
        if not isinstance(key, str) or isinstance(residual, bool) or not isinstance(residual, (int, float, np.integer, np.floating)) \
                or not math.isfinite(float(residual)):
            return f"{key!r}: {residual!r}; every residual must be a finite number under a text name"
    return None


def _labelled_body(value: Any, args: tuple) -> str | None:
    from allorules.body import Body

    given = args[0] if args else None
    if not isinstance(value, Body):
        return f"a {type(value).__name__}; a segmenter returns the Body it was given, labelled (docs/plugins.md)"
    if value.labels is None or not value.region_names:
        return "a body without labels; set labels (one region index per vertex) and region_names"
    if given is not None and len(value.vertices) != len(given.vertices):
        return f"a body with {len(value.vertices)} vertices for one of {len(given.vertices)}; label the body it was given"
    if not all(isinstance(name, str) and name for name in value.region_names):
        return "region names that are not all non-empty text"
    if value.labels.min(initial=0) < -1 or value.labels.max(initial=0) >= len(value.region_names):
        return "labels that are not indices into region_names (or -1 for unlabelled)"
    return None


def _lookup(table: dict[str, Any], name: str, kind: str) -> Any:
    if name in table:
        return table[name]
    from difflib import get_close_matches

    close = get_close_matches(name, list(table), n=1)
    hint = f"did you mean {close[0]!r}? " if close else ""
    raise PluginError(f"unknown {kind} {name!r}; {hint}known: {', '.join(sorted(table)) or 'none'} "
                      f"(a plugin may provide it: see 'allorules plugins')")


def _one_line(error: BaseException) -> str:
    text = str(error).strip().splitlines()
    return text[0] if text else type(error).__name__


def registry_for(arguments_or_paths: argparse.Namespace | Iterable[str | Path] | None = None, *,
                 entry_points: bool = True) -> PluginRegistry:
    """A registry with the built-ins, the installed plugins and the given plugin paths.

    ``arguments_or_paths`` is a parsed command line (its ``plugins`` from
    :func:`add_plugin_argument`) or an iterable of paths.
    """
    if isinstance(arguments_or_paths, argparse.Namespace):
        paths = list(getattr(arguments_or_paths, "plugins", None) or [])
    else:
        paths = list(arguments_or_paths or [])
    registry = PluginRegistry()
    registry.load_builtins()
    if entry_points:
        registry.load_entry_points()
    registry.load_paths(paths)
    return registry

