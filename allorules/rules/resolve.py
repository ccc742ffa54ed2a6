"""Loading a ruleset: read it (by name or path), resolve ``extends`` (overriding or removing
single rules and constraints), validate it against the published JSON Schema and against the
registered plugins (measures, constraints and their parameters, the segmenter and its options),
and build the :class:`~allorules.rules.model.Ruleset`. Every problem is a
:class:`~allorules.errors.RulesetError` naming file and line (several: ``RulesetProblems``).

The format is documented in ``docs/rulesets.md``.
"""
from __future__ import annotations

import difflib
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping

from allorules.errors import RulesetError, RulesetProblems, SourceLocation
from allorules.plugins.specs import parameter_problems
from allorules.rules.find import _registry, find_ruleset, looks_like_path, ruleset_path
from allorules.rules.located_yaml import LocatedDocument, _kind, read_located_yaml
from allorules.rules.model import (
    DEFAULT_SEGMENTER,
    LIMB_THICKNESS,
    OPEN_REGION_HOLDS,
    OPEN_REGION_SETTINGS,
    POSTURES,
    RULED_SHAPES,
    TRANSFORM_FORMS,
    TRUNK_HOLD,
    TRUNK_STRETCH,
    BodyMassTerm,
    ConstraintUse,
    OpenRegions,
    Rule,
    Ruleset,
    SegmenterUse,
    SolverSettings,
)
from allorules.rules.schema import _schema_problems

if TYPE_CHECKING:  # pragma: no cover
    from allorules.plugins.registry import PluginRegistry

MAX_EXTENDS_DEPTH = 32


# ---------------------------------------------------------------------------------------------
# The model
# ---------------------------------------------------------------------------------------------


# ---------------------------------------------------------------------------------------------
# Reading YAML with line numbers
# ---------------------------------------------------------------------------------------------


def _read_document(path: Path) -> LocatedDocument:
    document = read_located_yaml(path)
    if not isinstance(document.data, dict):
        raise RulesetError(f"a ruleset is a mapping of keys (name, regions, rules, ...), not {_kind(document.data)}",
                           document.at())
    return document


# ---------------------------------------------------------------------------------------------
# Schema validation
# ---------------------------------------------------------------------------------------------


# ---------------------------------------------------------------------------------------------
# Finding rulesets
# ---------------------------------------------------------------------------------------------


# ---------------------------------------------------------------------------------------------
# Resolving extends
# ---------------------------------------------------------------------------------------------
@dataclass
class _Entry:
    """A rule or constraint while ``extends`` is resolved: its keys and where each was written."""

    fields: dict[str, Any]
    where: dict[str, SourceLocation]
    location: SourceLocation


@dataclass
class _Merged:
    """A ruleset document with its ``extends`` chain applied, locations kept for later errors."""

    path: Path
    name: str
    values: dict[str, Any] = field(default_factory=dict)        # description, regions, segmenter
    where: dict[str, SourceLocation] = field(default_factory=dict)
    body_mass: dict[str, Any] = field(default_factory=dict)
    body_mass_where: dict[str, SourceLocation] = field(default_factory=dict)
    solver: dict[str, Any] = field(default_factory=dict)
    solver_where: dict[str, SourceLocation] = field(default_factory=dict)
    open_regions: dict[str, Any] = field(default_factory=dict)
    open_regions_where: dict[str, SourceLocation] = field(default_factory=dict)
    rules: dict[str, _Entry] = field(default_factory=dict)
    constraints: dict[str, _Entry] = field(default_factory=dict)
    plugins: list[tuple[Path, SourceLocation]] = field(default_factory=list)
    chain: list[str] = field(default_factory=list)
    segmenter_document: LocatedDocument | None = None   # the file that chose the segmenter (its folder, its lines)


def _resolve(path: Path, registry: "PluginRegistry", visiting: tuple[Path, ...]) -> _Merged:
    path = path.resolve()
    document = _read_document(path)
    problems = _schema_problems(document)
    if problems:
        raise RulesetProblems(problems)
    data = document.data
    if "extends" in data:
        parent_name = data["extends"]
        at = document.at("extends")
        parent_path = _extends_target(parent_name, path, registry, at)
        chain = visiting + (path,)
        if parent_path.resolve() in chain:
            cycle = " → ".join(p.name for p in chain + (parent_path.resolve(),))
            raise RulesetError(f"circular extends: {cycle}; remove one of these extends", at)
        if len(chain) > MAX_EXTENDS_DEPTH:
            raise RulesetError(f"extends goes more than {MAX_EXTENDS_DEPTH} rulesets deep; flatten the chain", at)
        try:
            merged = _resolve(parent_path, registry, chain)
        except RulesetProblems:
            raise
        except RulesetError as error:
            if error.location is None:   # say which extends led there
                raise RulesetError(str(error), at) from None
            raise
        merged.chain = [merged.name] + merged.chain
        merged.path = path
    else:
        merged = _Merged(path=path, name="")
    merged.name = data.get("name", path.stem)
    _apply(document, merged)
    return merged


def _extends_target(value: str, path: Path, registry: "PluginRegistry", at: SourceLocation) -> Path:
    if looks_like_path(value):
        target = (path.parent / Path(value).expanduser()).resolve()
        if not target.is_file():
            raise RulesetError(f"extends {value!r}: no such file {target}; paths are relative to this ruleset's folder", at)
        return target
    return find_ruleset(value, registry, at)


def _apply(document: LocatedDocument, merged: _Merged) -> None:
    """Lay one document over what it extends (``merged``), in place."""
    data = document.data
    for key in ("description", "regions", "segmenter"):
        if key in data:
            merged.values[key] = data[key]
            merged.where[key] = document.at(key)
    if "segmenter" in data:
        merged.segmenter_document = document
    for section, target, target_where in (("body_mass", merged.body_mass, merged.body_mass_where),
                                          ("solver", merged.solver, merged.solver_where)):
        for key, value in data.get(section, {}).items():
            target[key] = value
            target_where[key] = document.at(section, key)
    _apply_open_regions(document, merged)
    for entry_path in data.get("plugins", []):
        location = document.at("plugins", data["plugins"].index(entry_path))
        plugin_path = (document.path.parent / Path(entry_path).expanduser()).resolve()
        if plugin_path not in [p for p, _ in merged.plugins]:
            merged.plugins.append((plugin_path, location))
    is_child = "extends" in data
    for section, label, table in (("rules", "id", merged.rules), ("constraints", "name", merged.constraints)):
        kind = "rule" if section == "rules" else "constraint"
        problems: list[RulesetError] = []
        seen: set[str] = set()
        for index, entry in enumerate(data.get(section, [])):
            key = entry[label]
            location = document.at(section, index)
            if key in seen:
                problems.append(RulesetError(f"{kind} {key!r} is given twice in this file; keep one "
                                             f"(to change an inherited {kind}, give only the keys that change)",
                                             document.at(section, index, label)))
                continue
            seen.add(key)
            if entry.get("remove"):
                others = sorted(set(entry) - {label, "remove"})
                if others:
                    problems.append(RulesetError(f"{kind} {key!r} has remove: true and also {', '.join(others)}; "
                                                 f"a removed {kind} takes only {label} and remove", location))
                elif key not in table:
                    what = "the ruleset it extends" if is_child else "anything: this ruleset extends nothing"
                    problems.append(RulesetError(f"cannot remove {kind} {key!r}: it is not in {what}; "
                                                 f"known: {', '.join(table) or 'none'}", location))
                else:
                    del table[key]
                continue
            where = {name: document.at(section, index, name) for name in entry}
            if key in table:   # override only the keys given
                inherited = table[key]
                fields = dict(inherited.fields)
                merged_where = dict(inherited.where)
                for name, value in entry.items():
                    if name == "parameters" and isinstance(fields.get("parameters"), dict):
                        fields["parameters"] = {**fields["parameters"], **value}
                    else:
                        fields[name] = value
                    merged_where[name] = where[name]
                for name in entry.get("parameters", {}):
                    merged_where[f"parameters.{name}"] = document.at(section, index, "parameters", name)
                changed = [name for name in ("exponent", "region", "measure", "parameters") if name in entry]
                if changed and "source" not in entry:   # an inherited source no longer vouches for the value
                    old = " ".join(str(inherited.fields.get("source", "")).split())
                    fields["source"] = (f"{', '.join(changed)} overridden in {document.path.name}"
                                        + (f"; before: {old}" if old else ""))
                    merged_where["source"] = location
                table[key] = _Entry(fields, merged_where, location)
            else:
                for name in entry.get("parameters", {}):
                    where[f"parameters.{name}"] = document.at(section, index, "parameters", name)
                table[key] = _Entry(dict(entry), where, location)
        if problems:
            raise RulesetProblems(problems)


# ---------------------------------------------------------------------------------------------
# Checking the resolved ruleset against the registered plugins
# ---------------------------------------------------------------------------------------------
def _build(merged: _Merged, registry: "PluginRegistry") -> Ruleset:
    problems: list[RulesetError] = []
    plugin_failures_before = len(registry.failures)
    for plugin_path, location in merged.plugins:
        if registry.load_path(plugin_path) is None:
            message = registry.failures[-1].message if len(registry.failures) > plugin_failures_before else "failed to load"
            problems.append(RulesetError(f"plugin {plugin_path.name}: {message}", location))
    measures = registry.measures()
    constraints = registry.constraints()
    segmenters = registry.segmenters()
    failed_note = _failed_plugins_note(registry)
    whole = SourceLocation(merged.path, 1)

    regions = merged.values.get("regions")
    if regions is None:
        problems.append(RulesetError("the ruleset names no regions; add 'regions: [head, neck, ...]' "
                                     "(or extend a ruleset that has them)", whole))
        regions = []
    regions = tuple(regions)
    regions_text = ", ".join(regions) or "none"

    def check_region(region: Any, spec: Any, what: str, location: SourceLocation) -> None:
        if region is None:
            if spec is not None and spec.needs_region:
                problems.append(RulesetError(f"{what}: measure {spec.name!r} needs a region; add 'region:' "
                                             f"(one of {regions_text})", location))
            return
        if spec is not None and not spec.accepts_region:
            problems.append(RulesetError(f"{what}: measure {spec.name!r} is taken on the whole body; "
                                         "remove 'region' (or set it to null)", location))
        elif region not in regions:
            close = difflib.get_close_matches(region, regions, n=1)
            hint = f"did you mean {close[0]!r}? " if close else ""
            regions_at = merged.where.get("regions")
            set_at = f" (regions set at {regions_at})" if regions_at and regions_at.path != location.path else ""
            problems.append(RulesetError(f"{what}: unknown region {region!r}; {hint}the ruleset's regions are "
                                         f"{regions_text}{set_at} (add it to 'regions' if it is new)", location))

    def check_measure(name: str, what: str, location: SourceLocation):
        if name in measures:
            return measures[name]
        close = difflib.get_close_matches(name, list(measures), n=1)
        hint = f"did you mean {close[0]!r}? " if close else ""
        problems.append(RulesetError(f"{what}: unknown measure {name!r}; {hint}known measures: "
                                     f"{', '.join(sorted(measures))}{failed_note} (plugins add more: 'allorules plugins')",
                                     location))
        return None

    # body mass
    body_fields = {"measure": "mass", "region": None, "weight": 1.0, "source": "", **merged.body_mass}
    body_where = merged.body_mass_where
    body_spec = check_measure(body_fields["measure"], "body_mass", body_where.get("measure", whole))
    if body_spec is not None and body_spec.kind != "mass":
        problems.append(RulesetError(f"body_mass: measure {body_spec.name!r} measures {body_spec.kind}, not mass; "
                                     "use a mass measure (mass)", body_where.get("measure", whole)))
    if body_fields["region"] is not None:
        check_region(body_fields["region"], body_spec, "body_mass", body_where.get("region", whole))
    _check_finite(body_fields["weight"], "body_mass weight", body_where.get("weight", whole), problems)
    body_mass = BodyMassTerm(body_fields["measure"], body_fields["region"], float(body_fields["weight"]),
                             _text(body_fields["source"]))

    # rules
    rules = []
    for rule_id, entry in merged.rules.items():
        what = f"rule {rule_id!r}"
        missing = [key for key in ("measure", "exponent") if key not in entry.fields]
        if missing:
            problems.append(RulesetError(f"{what} is missing {', '.join(repr(m) for m in missing)}; a new rule needs "
                                         "measure and exponent (and region for a regional measure)", entry.location))
            continue
        spec = check_measure(entry.fields["measure"], what, entry.where.get("measure", entry.location))
        region = entry.fields.get("region")
        check_region(region, spec, what, entry.where.get("region", entry.location))
        exponent = entry.fields["exponent"]
        exponent_at = entry.where.get("exponent", entry.location)
        if _check_finite(exponent, f"{what} exponent", exponent_at, problems) and spec is not None:
            problem = exponent_problem(exponent, spec)
            if problem:
                problems.append(RulesetError(f"{what}: {problem}", exponent_at))
        weight = entry.fields.get("weight", 1.0)
        _check_finite(weight, f"{what} weight", entry.where.get("weight", entry.location), problems)
        rules.append(Rule(rule_id, region, entry.fields["measure"], float(exponent), float(weight),
                          _text(entry.fields.get("source", ""))))

    # constraints
    uses = []
    for name, entry in merged.constraints.items():
        what = f"constraint {name!r}"
        spec = constraints.get(name)
        if spec is None:
            close = difflib.get_close_matches(name, list(constraints), n=1)
            hint = f"did you mean {close[0]!r}? " if close else ""
            problems.append(RulesetError(f"{what} is not provided by any plugin; {hint}known constraints: "
                                         f"{', '.join(sorted(constraints)) or 'none'}{failed_note} "
                                         "(name the plugin under 'plugins:' or install it)", entry.location))
            continue
        given = entry.fields.get("parameters", {}) or {}
        found = parameter_problems(given, spec.parameter_specs())
        for parameter, problem in found:
            at = entry.where.get(f"parameters.{parameter}", entry.where.get("parameters", entry.location))
            got = f" (got {_kind(given[parameter])})" if parameter in spec.parameter_specs() and parameter in given else ""
            problems.append(RulesetError(f"{what}: {problem}{got}", at))
        ok = not found
        weight = entry.fields.get("weight", 1.0)
        _check_finite(weight, f"{what} weight", entry.where.get("weight", entry.location), problems)
        if ok:
            uses.append(ConstraintUse(name, spec.complete_parameters(given), float(weight),
                                      _text(entry.fields.get("source", ""))))

    # solver
    solver = _build_solver(merged, problems)
    open_regions = _build_open_regions(merged, measures, problems)

    segmenter = _build_segmenter(merged, segmenters, problems, failed_note)
    if problems:
        problems.sort(key=lambda p: (str(p.location.path), p.location.line or 0) if p.location else ("", 0))
        raise RulesetProblems(problems)
    return Ruleset(
        name=merged.name,
        description=" ".join(str(merged.values.get("description", "")).split()),
        path=merged.path,
        regions=regions,
        rules=tuple(rules),
        body_mass=body_mass,
        constraints=tuple(uses),
        solver=solver,
        plugins=tuple(p for p, _ in merged.plugins),
        segmenter=segmenter,
        extends=tuple(merged.chain),
        open_regions=open_regions,
    )


def _build_segmenter(merged: _Merged, segmenters: dict, problems: list[RulesetError], failed_note: str) -> SegmenterUse:
    """The ruleset's segmenter with its options checked against the segmenter's parameters."""
    value = merged.values.get("segmenter", DEFAULT_SEGMENTER)
    document = merged.segmenter_document
    name, given = (value, {}) if isinstance(value, str) else (value["name"], dict(value.get("options") or {}))
    at = merged.where.get("segmenter", SourceLocation(merged.path, 1))
    spec = segmenters.get(name)
    if spec is None:
        close = difflib.get_close_matches(name, list(segmenters), n=1)
        hint = f"did you mean {close[0]!r}? " if close else ""
        problems.append(RulesetError(f"unknown segmenter {name!r}; {hint}known: {', '.join(sorted(segmenters))}"
                                     f"{failed_note}", document.at("segmenter", "name") if document and given else at))
        return SegmenterUse(name)
    specs = spec.parameter_specs()
    for option, problem in parameter_problems(given, specs, word="option"):
        if option not in given:        # a required option left out
            problems.append(RulesetError(f"segmenter {name!r}: {problem}; write segmenter: {{name: {name}, options: "
                                         f"{{{option}: ...}}}}", at))
        elif option not in specs:      # a name it does not know
            problems.append(RulesetError(f"segmenter {name!r}: {problem}", document.key_at("segmenter", "options", option)))
        else:
            problems.append(RulesetError(f"segmenter {name!r}: {problem} (got {_kind(given[option])})",
                                         document.at("segmenter", "options", option)))
    options: dict[str, Any] = {}
    for option, option_value in given.items():
        if option in specs and specs[option].kind is Path and option_value is not None:   # relative to the ruleset
            base = document.path.parent if document else merged.path.parent
            option_value = (base / Path(str(option_value)).expanduser()).resolve()
        options[option] = option_value
    return SegmenterUse(name, options)


def _text(value: Any) -> str:
    """Folded YAML text as one line (sources and descriptions)."""
    return " ".join(str(value or "").split())


def exponent_problem(exponent: float, spec: Any) -> str | None:
    """Why ``exponent`` is not sane for the measure ``spec`` (None when it is).

    Sane means within ±1 of the measure's isometric exponent (``specs.EXPONENT_RANGE``):
    length in [-2/3, 4/3], mass in [0, 2], area in [-1/3, 5/3].
    """
    low, high = spec.exponent_range()
    if low - 1e-12 <= exponent <= high + 1e-12:
        return None
    return (f"exponent {exponent:g} is outside the sane range [{low:.3g}, {high:.3g}] for measure {spec.name!r} "
            f"(isometric {spec.isometric_exponent:.4g} ± 1); check for a typo")


def _check_finite(value: Any, what: str, location: SourceLocation, problems: list[RulesetError]) -> bool:
    try:
        ok = math.isfinite(float(value))
    except (TypeError, ValueError, OverflowError):
        ok = False
    if not ok:
        problems.append(RulesetError(f"{what} must be a finite number, not {_kind(value)}", location))
    return ok


def _failed_plugins_note(registry: "PluginRegistry") -> str:
    failed = sorted({failure.plugin for failure in registry.failures})
    return f"; plugins that failed to load: {', '.join(failed)}" if failed else ""


def _apply_open_regions(document: LocatedDocument, merged: _Merged) -> None:
    """Lay a document's ``open_regions`` over the inherited one: a word (isometric / free) sets the
    default; a mapping merges key by key (``regions`` region by region)."""
    value = document.data.get("open_regions")
    if value is None:
        return
    if isinstance(value, str):
        merged.open_regions["default"] = value
        merged.open_regions_where["default"] = document.at("open_regions")
        return
    for key, item in value.items():
        if key == "regions" and isinstance(item, dict):
            regions = dict(merged.open_regions.get("regions", {}))
            for region, setting in item.items():
                regions[region] = setting
                merged.open_regions_where[f"regions.{region}"] = document.at("open_regions", "regions", region)
            merged.open_regions["regions"] = regions
        else:
            merged.open_regions[key] = item
            merged.open_regions_where[key] = document.at("open_regions", key)


def _take_choice(values: Mapping[str, Any], key: str, choices, settings: dict[str, Any],
                 problems: list[RulesetError], location, message) -> None:
    """``settings[key]`` = ``values[key]`` when it is one of ``choices``; otherwise a problem at
    ``location`` saying ``message(value)``. Nothing when the key is not given."""
    if key not in values:
        return
    if values[key] in choices:
        settings[key] = values[key]
    else:
        problems.append(RulesetError(message(values[key]), location))


def _build_open_regions(merged: _Merged, measures: Mapping[str, Any], problems: list[RulesetError]) -> OpenRegions:
    values, where = merged.open_regions, merged.open_regions_where
    whole = SourceLocation(merged.path, 1)
    settings: dict[str, Any] = {}
    choices = " or ".join(repr(choice) for choice in OPEN_REGION_SETTINGS)
    _take_choice(values, "default", OPEN_REGION_SETTINGS, settings, problems, where.get("default", whole),
                 lambda value: f"open_regions {value!r} is not {choices} (isometric: regions no rule measures keep "
                               "their proportions; free: the solver may change them)")
    holds = " or ".join(repr(choice) for choice in OPEN_REGION_HOLDS)
    _take_choice(values, "hold", OPEN_REGION_HOLDS, settings, problems, where.get("hold", whole),
                 lambda value: f"open_regions.hold {value!r} is not {holds} (shape: each open region keeps its input "
                               "shape, scaled isometrically; soft: energy terms on its measures)")
    if "weight" in values and _check_finite(values["weight"], "open_regions.weight", where.get("weight", whole), problems):
        settings["weight"] = float(values["weight"])
    if "measures" in values:
        names = []
        for name in values["measures"]:
            spec = measures.get(name)
            if spec is None or not spec.accepts_region:
                known = sorted(n for n, m in measures.items() if m.accepts_region)
                close = difflib.get_close_matches(str(name), known, n=1)
                hint = f"did you mean {close[0]!r}? " if close else ""
                problems.append(RulesetError(f"open_regions.measures: {name!r} is not a measure of a region; {hint}"
                                             f"known: {', '.join(known)}", where.get("measures", whole)))
            else:
                names.append(name)
        settings["measures"] = tuple(names)
    regions = {}
    for region, setting in values.get("regions", {}).items():
        if setting in OPEN_REGION_SETTINGS:
            regions[region] = setting
        else:
            problems.append(RulesetError(f"open_regions.regions.{region}: {setting!r} is not {choices}",
                                         where.get(f"regions.{region}", whole)))
    settings["regions"] = regions
    if "source" in values:
        settings["source"] = _text(values["source"])
    return replace(OpenRegions(), **settings)


def _build_solver(merged: _Merged, problems: list[RulesetError]) -> SolverSettings:
    defaults = SolverSettings()
    values = dict(merged.solver)
    where = merged.solver_where
    whole = SourceLocation(merged.path, 1)
    settings: dict[str, Any] = {}
    for key in ("step_ratio_up", "step_ratio_down", "relative_tolerance", "parameter_tolerance"):
        if key in values and _check_finite(values[key], f"solver.{key}", where.get(key, whole), problems):
            settings[key] = float(values[key])
    if "max_evaluations" in values:
        settings["max_evaluations"] = int(values["max_evaluations"])
    for key in ("scale_bounds", "alpha_bounds"):
        if key not in values:
            continue
        at = where.get(key, whole)
        low, high = values[key]
        if not (_check_finite(low, f"solver.{key} lower", at, problems)
                and _check_finite(high, f"solver.{key} upper", at, problems)):
            continue
        if not low < high:
            problems.append(RulesetError(f"solver.{key} must be [lower, upper] with lower < upper, not {values[key]}", at))
            continue
        if key == "scale_bounds" and not (0 < low <= 1 <= high):
            problems.append(RulesetError(f"solver.scale_bounds must satisfy 0 < lower <= 1 <= upper (s = 1 is no "
                                         f"change), not {values[key]}", at))
            continue
        if key == "alpha_bounds" and not (low <= 0 <= high):
            problems.append(RulesetError(f"solver.alpha_bounds must contain 0 (α = 0 is no change), not {values[key]}", at))
            continue
        settings[key] = (float(low), float(high))
    _take_choice(values, "transform", TRANSFORM_FORMS, settings, problems, where.get("transform", whole),
                 lambda value: f"solver.transform {value!r} is not a transform form; use {' or '.join(TRANSFORM_FORMS)}")
    _take_choice(values, "posture", POSTURES, settings, problems, where.get("posture", whole),
                 lambda value: f"solver.posture {value!r} is not one of 'keep' (legs upright and feet on the ground), "
                               "'upright' (legs upright) or 'free' (as Eq. 9 leaves them)")
    _take_choice(values, "ruled_shape", RULED_SHAPES, settings, problems, where.get("ruled_shape", whole),
                 lambda value: f"solver.ruled_shape {value!r} is not one of 'hold' (a head sized by its rule keeps its "
                               "shape) or 'reshape' (Eq. 9's α reshapes it)")
    for key, choices in (("trunk_stretch", TRUNK_STRETCH), ("limb_thickness", LIMB_THICKNESS), ("trunk_hold", TRUNK_HOLD)):
        if isinstance(values.get(key), bool):    # YAML reads a bare on/off (yes/no) as a boolean
            values = {**values, key: "on" if values[key] else "off"}
        _take_choice(values, key, choices, settings, problems, where.get(key, whole),
                     lambda value, key=key, choices=choices:
                     f"solver.{key} {value!r} is not one of {', '.join(map(repr, choices))}")
    if "detail_cutoff" in values:
        cutoff = values["detail_cutoff"]
        if cutoff is None:
            settings["detail_cutoff"] = None
        elif _check_finite(cutoff, "solver.detail_cutoff", where.get("detail_cutoff", whole), problems):
            if float(cutoff) > 0:
                settings["detail_cutoff"] = float(cutoff)
            else:
                problems.append(RulesetError(f"solver.detail_cutoff must be a positive number of modes (or null), not "
                                             f"{cutoff!r}", where.get("detail_cutoff", whole)))
    if "algorithm" in values:
        algorithm = values["algorithm"]
        try:
            import nlopt

            valid = isinstance(getattr(nlopt, algorithm, None), int)
        except ImportError:  # pragma: no cover - nlopt is a dependency
            valid = True
        if not valid:
            problems.append(RulesetError(f"solver.algorithm {algorithm!r} is not an nlopt algorithm; use LN_BOBYQA, "
                                         "LN_COBYLA, LN_NELDERMEAD or LN_SBPLX", where.get("algorithm", whole)))
        else:
            settings["algorithm"] = algorithm
    return replace(defaults, **settings)


# ---------------------------------------------------------------------------------------------
# Public functions
# ---------------------------------------------------------------------------------------------


def load_ruleset(name_or_path: str | Path, plugin_manager: "PluginRegistry | None" = None) -> Ruleset:
    """Read, resolve (``extends``) and validate a ruleset given by name or by file path.

    Plugins the ruleset names under ``plugins:`` are loaded into ``plugin_manager`` (a
    :class:`~allorules.plugins.PluginRegistry`; a fresh one with the built-ins and the
    installed plugins when ``None``), so pass the registry the solver will use. Every problem
    raises :class:`RulesetError` (:class:`RulesetProblems` when there are several).
    """
    registry = _registry(plugin_manager)
    path = ruleset_path(name_or_path, registry)
    merged = _resolve(path, registry, ())
    return _build(merged, registry)


def check_ruleset(name_or_path: str | Path, plugin_manager: "PluginRegistry | None" = None) -> list[RulesetError]:
    """Every problem of a ruleset (empty when it is valid)."""
    try:
        load_ruleset(name_or_path, plugin_manager)
    except RulesetProblems as problems:
        return problems.problems
    except RulesetError as error:
        return [error]
    return []


