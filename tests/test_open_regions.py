"""Open regions are isometric by default (METHOD §10, issue 18)."""
from __future__ import annotations

import pytest
import yaml

from allorules.errors import RulesetError
from allorules.plugins.registry import registry_for
from allorules.rules.model import OpenRegions, ruleset_to_dict
from allorules.rules.resolve import check_ruleset, load_ruleset
from allorules.solve.open_regions import extra_regions, open_regions, shape_held_regions


def _write(tmp_path, text, name="set.yaml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_default_is_isometric_length_and_mass():
    ruleset = load_ruleset("quadruped")
    assert ruleset.open_regions == OpenRegions()
    assert ruleset.open_regions.default == "isometric" and ruleset.open_regions.hold == "shape"
    assert ruleset.open_regions.measures == ("length", "mass")


def test_word_mapping_and_per_region_settings(tmp_path):
    free = load_ruleset(_write(tmp_path, "extends: quadruped\nopen_regions: free\n"))
    assert free.open_regions.default == "free"
    mixed = load_ruleset(_write(tmp_path, "extends: quadruped\nopen_regions:\n  default: free\n  weight: 0.5\n"
                                          "  measures: [length]\n  regions: {neck: isometric, tail: isometric}\n"))
    assert mixed.open_regions.setting("neck") == "isometric"
    assert mixed.open_regions.setting("chest") == "free"
    assert mixed.open_regions.weight == 0.5 and mixed.open_regions.measures == ("length",)
    # a child overrides one region and keeps the rest
    child = load_ruleset(_write(tmp_path, f"extends: {tmp_path / 'set.yaml'}\nopen_regions:\n  regions: {{tail: free}}\n",
                                "child.yaml"))
    assert child.open_regions.setting("tail") == "free" and child.open_regions.setting("neck") == "isometric"
    # the resolved document loads back into the same setting
    again = load_ruleset(_write(tmp_path, yaml.safe_dump(ruleset_to_dict(mixed)), "again.yaml"))
    assert again.open_regions == mixed.open_regions


@pytest.mark.parametrize("text, expected", [
    ("open_regions: frea\n", "2:15: open_regions must be 'isometric', 'free' or a mapping"),
    ("open_regions:\n  defualt: free\n", "3:3: unknown key 'defualt' in open_regions; did you mean 'default'?"),
    ("open_regions:\n  measures: [lenght]\n", "3:13: open_regions.measures: 'lenght' is not a measure of a region; did you mean 'length'?"),
    ("open_regions:\n  regions: {neck: iso}\n", "3:19: open_regions.regions.neck 'iso' is not one of 'isometric', 'free'"),
    ("open_regions: 3\n", "2:15: open_regions must be 'isometric', 'free' or a mapping"),
    ("open_regions:\n  hold: shap\n", "3:9: open_regions.hold 'shap' is not one of 'shape', 'soft'"),
    ("solver:\n  detail_cutoff: -3\n", "3:18: solver.detail_cutoff must be a positive number of modes or null"),
])
def test_bad_settings_name_file_and_line(tmp_path, text, expected):
    path = _write(tmp_path, "extends: quadruped\n" + text)
    problems = check_ruleset(path)
    assert problems and isinstance(problems[0], RulesetError)
    assert f"{path}:{expected}" in str(problems[0]), str(problems[0])


def test_a_rule_replaces_the_default_and_appendages_are_open(generated_horse, tmp_path):
    body = generated_horse.body()            # the generator's labels include a tail
    quadruped = load_ruleset("quadruped")
    # held by their shape (the default), appendages are open too and need no α of their own
    assert open_regions(quadruped, body) == {"neck": "isometric", "tail": "isometric"}
    assert shape_held_regions(quadruped, body) == ("neck", "tail")
    assert extra_regions(quadruped, body, held=("neck", "tail")) == ()
    assert extra_regions(quadruped, body, held=("neck",)) == ("tail",)    # a tail the shape cannot hold: soft, its own α
    # held by soft terms (today's behaviour), appendages only when named, each with an α of its own
    soft = load_ruleset(_write(tmp_path, "extends: quadruped\nopen_regions: {hold: soft}\n", "soft.yaml"))
    assert open_regions(soft, body) == {"neck": "isometric"}
    assert shape_held_regions(soft, body) == () and extra_regions(soft, body) == ()
    named = load_ruleset(_write(tmp_path, "extends: quadruped\nopen_regions:\n  hold: soft\n  regions: {tail: isometric}\n"))
    assert open_regions(named, body) == {"neck": "isometric", "tail": "isometric"}
    assert extra_regions(named, body) == ("tail",)
    override = load_ruleset("neck-override")
    assert "neck" not in open_regions(override, body)         # its neck-length rule replaces the default


@pytest.mark.slow
@pytest.mark.heavy
def test_soft_terms_hold_the_open_neck_when_asked_and_neck_override_still_controls(tmp_path):
    """The demo's animal (2,000 vertices, 120 modes) at ×2: held by soft terms of weight 1 (a ruleset's
    open_regions; the shape hold, the default, is tests/test_held_regions.py), the open neck's length and mass exponents stay within ±0.02 of 1/3 and 1 (it was
    free before and grew: neck/body 0.177 → 0.228 with this measure); neck-override's rule still
    moves it where it is told. (The default weight, 0.01, keeps every rule converging on the test
    animals but holds the neck only loosely: docs/method.md, open regions.)"""
    from allorules.body import Body
    from allorules.mesh.quadruped import generate_quadruped
    from allorules.runs.ruleset_run import scale_with_ruleset
    from allorules.segment.labeller import label_quadruped

    generated = generate_quadruped("horse", 2000)
    body = label_quadruped(Body(generated.vertices, generated.faces))
    registry = registry_for(None)
    held = load_ruleset(_write(tmp_path, "extends: quadruped\nopen_regions: {hold: soft, weight: 1}\n"), registry)
    result = scale_with_ruleset(body, held, 2.0, registry=registry, modes=120, use_cache=False)
    # every rule met, and the trunk within the verdict's check (at 60 modes what the neck no
    # longer took the trunk did, its length growing at 0.49, and the mass missed by 1.1 %)
    assert all(abs(rule.achieved_exponent - rule.exponent) <= 0.02 for rule in result.rules), result.messages
    assert result.converged, result.messages
    neck = {outcome.measure: outcome for outcome in result.open_regions if outcome.region == "neck"}
    assert abs(neck["length"].achieved_exponent - 1 / 3) <= 0.02
    assert abs(neck["mass"].achieved_exponent - 1.0) <= 0.02
    assert all(outcome.met for outcome in result.open_regions)
    assert "open_regions" in result.as_dict()
    ruleset = load_ruleset(_write(tmp_path, "extends: neck-override\nrules:\n  - id: neck-length\n    exponent: 0.5\n"),
                           registry)
    controlled = scale_with_ruleset(body, ruleset, 2.0, registry=registry, modes=60, use_cache=False)
    achieved = {rule.id: rule.achieved_exponent for rule in controlled.rules}
    assert abs(achieved["neck-length"] - 0.5) <= 0.02
    assert not [outcome for outcome in controlled.open_regions if outcome.region == "neck"]


def test_appendages_are_kept_apart_when_held_by_their_shape_or_named(tmp_path):
    """Folded into its neighbour (segment/regions.py) a tail takes the abdomen's exponent; held by
    its shape (the default) every appendage is kept as a region of its own, unless set free; with
    hold: soft only a named one is (it then needs an α of its own)."""
    from allorules.runs.pipeline import wanted_regions

    default = wanted_regions(load_ruleset("quadruped"))
    assert default[:6] == ("head", "neck", "chest", "abdomen", "forelimbs", "hindlimbs")
    assert {"tail", "ears", "horns", "trunk"} <= set(default)
    free = load_ruleset(_write(tmp_path, "extends: quadruped\nopen_regions:\n  regions: {tail: free}\n", "free.yaml"))
    assert "tail" not in wanted_regions(free) and "ears" in wanted_regions(free)
    soft = load_ruleset(_write(tmp_path, "extends: quadruped\nopen_regions: {hold: soft}\n", "soft.yaml"))
    assert wanted_regions(soft) == default[:6]
    named = load_ruleset(_write(tmp_path, "extends: quadruped\nopen_regions:\n  hold: soft\n  regions: {tail: isometric}\n"))
    assert wanted_regions(named) == default[:6] + ("tail",)


def test_the_terminal_says_what_each_open_region_reached():
    from allorules.cli.scale import open_regions_line
    from allorules.solve.open_regions import OpenRegionOutcome

    def outcome(region, measure, achieved, held=True):
        return OpenRegionOutcome(region, "isometric", measure, 1 / 3 if measure == "length" else 1.0, achieved, held,
                                 0.02, "shape" if held else None)

    line = open_regions_line([outcome("neck", "length", 0.334), outcome("neck", "mass", 0.965),
                              outcome("tail", "length", None), outcome("tail", "mass", 1.0),
                              outcome("ears", "length", 0.333), outcome("ears", "mass", 1.001),
                              outcome("horns", "length", 0.5, held=False), outcome("horns", "mass", 1.5, held=False)])
    assert line.startswith("open regions, length / mass exponents (isometric 0.333 / 1.000")
    # a held region beyond the tolerance, or not measured, is marked; one within it or not held is not
    assert "neck 0.334 / 0.965 NO" in line and "tail - / 1.000 NO" in line
    assert "ears 0.333 / 1.001," in line and line.endswith("horns 0.500 / 1.500")
