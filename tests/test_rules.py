"""Rulesets: built-in sets, schema round trip, extends, every error path with file:line, CLI."""
from __future__ import annotations

import json
import textwrap
from pathlib import Path

import jsonschema
import pytest
import yaml

from allorules.cli import main
from allorules.errors import RulesetError, RulesetProblems
from allorules.plugins.registry import registry_for
from allorules.rules.find import list_rulesets
from allorules.rules.model import Rule, ruleset_to_dict
from allorules.rules.overrides import override_exponents, parse_rule_overrides
from allorules.rules.resolve import check_ruleset, load_ruleset
from allorules.rules.schema import ruleset_schema

BUILTINS = ("quadruped", "intraspecies", "neck-override", "isometric", "cartoon")
REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def registry():
    return registry_for([], entry_points=False)


def write(folder: Path, name: str, text: str) -> Path:
    path = folder / name
    path.write_text(textwrap.dedent(text).lstrip("\n"), encoding="utf-8")
    return path


def problems_of(path, registry=None) -> list[str]:
    return [str(problem) for problem in check_ruleset(path, registry or registry_for([], entry_points=False))]


MINIMAL = """
name: tiny
regions: [body, legs]
rules:
  - id: leg-length
    region: legs
    measure: length
    exponent: 0.36
"""


# -- built-in rulesets ---------------------------------------------------------------------------
def test_quadruped_has_the_papers_exponents(registry):
    ruleset = load_ruleset("quadruped", registry)
    assert ruleset.regions == ("head", "neck", "chest", "abdomen", "forelimbs", "hindlimbs")
    expected = {"foreleg-length": ("forelimbs", "length", 0.360), "hindleg-length": ("hindlimbs", "length", 0.336),
                "chest-girth": ("chest", "girth", 0.365), "head-mass": ("head", "mass", 0.700),
                "abdomen-mass": ("abdomen", "mass", 0.740)}
    assert {rule.id: (rule.region, rule.measure, rule.exponent) for rule in ruleset.rules} == expected
    assert [use.name for use in ruleset.constraints] == ["terrestrial-limb-stress"]
    assert ruleset.constraints[0].parameters == {"exponent": 0.0}
    assert ruleset.solver.step_ratio_up == 1.1 and ruleset.solver.step_ratio_down == 0.9
    assert ruleset.body_mass.measure == "mass" and ruleset.body_mass.region is None


@pytest.mark.parametrize("name", BUILTINS)
def test_every_builtin_value_has_a_source(name, registry):
    ruleset = load_ruleset(name, registry)
    assert ruleset.description
    assert ruleset.body_mass.source
    for rule in ruleset.rules:
        assert len(rule.source) > 10, rule
    for use in ruleset.constraints:
        assert len(use.source) > 10, use


@pytest.mark.parametrize("name", BUILTINS)
def test_builtin_files_validate_against_the_published_schema(name):
    path = REPO / "rulesets" / f"{name}.yaml"
    jsonschema.validate(yaml.safe_load(path.read_text(encoding="utf-8")), ruleset_schema())


def test_isometric_sets_every_rule_to_its_measures_isometric_exponent(registry):
    ruleset = load_ruleset("isometric", registry)
    measures = registry.measures()
    assert len(ruleset.rules) == 6 and {rule.region for rule in ruleset.rules} == set(ruleset.regions)
    for rule in ruleset.rules:
        assert rule.exponent == pytest.approx(measures[rule.measure].isometric_exponent, abs=1e-12)
    assert ruleset.constraints == ()   # keeping σ would contradict uniform scaling (σ ∝ s)


def test_neck_override_is_quadruped_plus_an_isometric_neck(registry):
    quadruped = load_ruleset("quadruped", registry)
    neck = load_ruleset("neck-override", registry)
    assert neck.extends == ("quadruped",)
    assert neck.rules[:-1] == quadruped.rules
    assert neck.rules[-1].id == "neck-length" and neck.rules[-1].exponent == pytest.approx(1 / 3)
    raised = override_exponents(neck, {"neck-length": 0.45}, registry)
    assert raised.rule("neck-length").exponent == 0.45
    assert "command line" in raised.rule("neck-length").source
    assert neck.rule("neck-length").exponent == pytest.approx(1 / 3)   # the original is unchanged


def test_cartoon_is_quadruped_with_head_and_abdomen_mass_isometric(registry):
    """The ruleset a refused cartoon is pointed to: quadruped's every rule, constraint and setting,
    but the two mass rules at mass's isometric exponent."""
    quadruped = load_ruleset("quadruped", registry)
    cartoon = load_ruleset("cartoon", registry)
    assert cartoon.extends == ("quadruped",)
    held = {"head-mass", "abdomen-mass"}
    assert [rule.id for rule in cartoon.rules] == [rule.id for rule in quadruped.rules]
    for rule, theirs in zip(cartoon.rules, quadruped.rules):
        if rule.id in held:
            assert rule.exponent == registry.measures()["mass"].isometric_exponent == 1.0
            assert (rule.region, rule.measure, rule.weight) == (theirs.region, theirs.measure, theirs.weight)
        else:
            assert rule == theirs
    assert (cartoon.regions, cartoon.constraints, cartoon.solver, cartoon.body_mass) == \
        (quadruped.regions, quadruped.constraints, quadruped.solver, quadruped.body_mass)
    # what a refusal's --rule advice gives, and what the cartoon runs of docs/benchmarks.md were measured with
    advised = override_exponents(quadruped, {name: 1.0 for name in held}, registry)
    assert [(rule.id, rule.exponent) for rule in advised.rules] == [(rule.id, rule.exponent) for rule in cartoon.rules]


def test_intraspecies_keeps_maturation_head_and_marks_assumptions(registry):
    ruleset = load_ruleset("intraspecies", registry)
    assert ruleset.rule("head-mass").exponent == 0.7
    assert ruleset.rule("foreleg-length").exponent < 1 / 3
    assert "ASSUMPTION" in ruleset.rule("foreleg-length").source


def test_list_rulesets_names_the_builtins_with_descriptions(registry):
    summaries = {summary.name: summary for summary in list_rulesets(registry)}
    assert set(BUILTINS) <= set(summaries)
    assert all(summaries[name].description and summaries[name].origin == "built-in" for name in BUILTINS)


# -- round trip ----------------------------------------------------------------------------------
@pytest.mark.parametrize("name", BUILTINS)
def test_schema_round_trip(name, tmp_path, registry):
    ruleset = load_ruleset(name, registry)
    document = ruleset_to_dict(ruleset)
    jsonschema.validate(json.loads(json.dumps(document)), ruleset_schema())
    path = tmp_path / f"{name}-copy.yaml"
    path.write_text(yaml.safe_dump(document, sort_keys=False, allow_unicode=True), encoding="utf-8")
    again = load_ruleset(path, registry)
    assert again.rules == ruleset.rules
    assert again.constraints == ruleset.constraints
    assert again.solver == ruleset.solver
    assert again.body_mass == ruleset.body_mass
    assert (again.name, again.description, again.regions, again.segmenter) == \
        (ruleset.name, ruleset.description, ruleset.regions, ruleset.segmenter)
    assert ruleset_to_dict(again) == document


# -- extends -------------------------------------------------------------------------------------
def test_extends_overrides_single_keys_and_removes_rules(tmp_path, registry):
    path = write(tmp_path, "child.yaml", """
        extends: quadruped
        description: stocky
        rules:
          - id: foreleg-length
            exponent: 0.30
          - id: head-mass
            remove: true
          - id: tail-length
            region: tail
            measure: length
            exponent: 0.4
            source: my guess
        regions: [head, neck, chest, abdomen, forelimbs, hindlimbs, tail]
        constraints:
          - name: terrestrial-limb-stress
            weight: 2.5
        solver:
          max_evaluations: 50
        """)
    ruleset = load_ruleset(path, registry)
    parent = load_ruleset("quadruped", registry)
    assert ruleset.name == "child" and ruleset.description == "stocky"
    fore = ruleset.rule("foreleg-length")
    assert (fore.region, fore.measure, fore.exponent) == ("forelimbs", "length", 0.30)
    assert "overridden in child.yaml" in fore.source and "Prothero" in fore.source
    assert "head-mass" not in [rule.id for rule in ruleset.rules]
    assert ruleset.rules[-1] == Rule("tail-length", "tail", "length", 0.4, 1.0, "my guess")
    assert ruleset.rule("chest-girth") == parent.rule("chest-girth")
    assert ruleset.constraints[0].weight == 2.5 and ruleset.constraints[0].parameters == {"exponent": 0.0}
    assert ruleset.solver.max_evaluations == 50 and ruleset.solver.algorithm == parent.solver.algorithm


def test_extends_by_relative_path_through_two_levels(tmp_path, registry):
    (tmp_path / "sets").mkdir()
    write(tmp_path / "sets", "base.yaml", MINIMAL)
    write(tmp_path / "sets", "middle.yaml", """
        extends: base.yaml
        rules:
          - id: leg-length
            exponent: 0.3
        """)
    leaf = write(tmp_path, "leaf.yaml", """
        extends: sets/middle.yaml
        constraints:
          - name: terrestrial-limb-stress
            parameters: {exponent: 0.1}
        """)
    ruleset = load_ruleset(leaf, registry)
    assert ruleset.extends == ("middle", "tiny")   # nearest first
    assert ruleset.rule("leg-length").exponent == 0.3
    assert ruleset.constraints[0].parameters == {"exponent": 0.1}


def test_constraint_removed_through_extends(tmp_path, registry):
    path = write(tmp_path, "free.yaml", """
        extends: quadruped
        constraints:
          - name: terrestrial-limb-stress
            remove: true
        """)
    assert load_ruleset(path, registry).constraints == ()


# -- every error path: message and file:line ------------------------------------------------------
def single_problem(tmp_path, text, registry, name="broken.yaml"):
    path = write(tmp_path, name, text)
    problems = problems_of(path, registry)
    assert problems, "expected a problem"
    return path, problems


def test_yaml_syntax_error_names_file_and_line(tmp_path, registry):
    path, problems = single_problem(tmp_path, """
        name: x
        regions: [a, b
        rules: []
        """, registry)
    assert problems[0].startswith(f"{path.resolve()}:3") or problems[0].startswith(f"{path}:3")
    assert "YAML syntax error" in problems[0]


def test_unknown_key_suggests_the_right_one(tmp_path, registry):
    path, problems = single_problem(tmp_path, MINIMAL + "    exponnet: 0.3\n", registry)
    assert len(problems) == 1
    assert ":8:" in problems[0] and "unknown key 'exponnet'" in problems[0] and "did you mean 'exponent'" in problems[0]
    assert "rule 'leg-length'" in problems[0]


def test_unknown_top_level_key(tmp_path, registry):
    _, problems = single_problem(tmp_path, "regoins: [a]\n" + MINIMAL, registry)
    assert ":1:" in problems[0] and "unknown key 'regoins'" in problems[0] and "'regions'" in problems[0]


def test_unknown_region(tmp_path, registry):
    _, problems = single_problem(tmp_path, MINIMAL.replace("region: legs", "region: lgs"), registry)
    assert ":5:" in problems[0] and "unknown region 'lgs'" in problems[0] and "did you mean 'legs'" in problems[0]


def test_unknown_measure(tmp_path, registry):
    _, problems = single_problem(tmp_path, MINIMAL.replace("measure: length", "measure: lenght"), registry)
    assert ":6:" in problems[0] and "unknown measure 'lenght'" in problems[0] and "did you mean 'length'" in problems[0]


def test_unknown_constraint_and_parameter(tmp_path, registry):
    _, problems = single_problem(tmp_path, MINIMAL + textwrap.dedent("""
        constraints:
          - name: flying
          - name: terrestrial-limb-stress
            parameters: {exponant: 1}
        """), registry)
    assert any("constraint 'flying' is not provided by any plugin" in p and ":10:" in p for p in problems)
    assert any("unknown parameter 'exponant'" in p and "did you mean 'exponent'" in p and ":12:" in p for p in problems)


def test_constraint_parameter_type_and_range(tmp_path, registry):
    _, problems = single_problem(tmp_path, MINIMAL + textwrap.dedent("""
        constraints:
          - name: terrestrial-limb-stress
            parameters:
              exponent: lots
        """), registry)
    assert "parameter 'exponent' must be a number" in problems[0] and ":12:" in problems[0]
    _, problems = single_problem(tmp_path, MINIMAL + textwrap.dedent("""
        constraints:
          - name: terrestrial-limb-stress
            parameters: {exponent: 5}
        """), registry)
    assert "must be at most 1.0" in problems[0]


def test_unknown_plugin_path(tmp_path, registry):
    path, problems = single_problem(tmp_path, "plugins: [nowhere.py]\n" + MINIMAL, registry)
    assert ":1:" in problems[0] and "nowhere.py" in problems[0] and "does not exist" in problems[0]


def test_wrong_types(tmp_path, registry):
    _, problems = single_problem(tmp_path, MINIMAL.replace("exponent: 0.36", "exponent: big"), registry)
    assert ":7:" in problems[0] and "exponent' must be a number, not text ('big')" in problems[0]
    _, problems = single_problem(tmp_path, MINIMAL.replace("exponent: 0.36", "exponent: 1/3"), registry)
    assert "write the fraction as a decimal" in problems[0]
    _, problems = single_problem(tmp_path, MINIMAL.replace("regions: [body, legs]", "regions: body"), registry)
    assert ":2:" in problems[0] and "regions must be a list" in problems[0]
    _, problems = single_problem(tmp_path, MINIMAL + "solver: {max_evaluations: 1.5}\n", registry)
    assert "solver.max_evaluations must be a whole number" in problems[0]


def test_exponent_outside_sane_range(tmp_path, registry):
    _, problems = single_problem(tmp_path, MINIMAL.replace("exponent: 0.36", "exponent: 3.6"), registry)
    assert ":7:" in problems[0] and "outside the sane range [-0.667, 1.33]" in problems[0]
    # the edge of the range is allowed, just beyond it is not
    assert problems_of(write(tmp_path, "edge.yaml", MINIMAL.replace("exponent: 0.36", "exponent: 1.3333")), registry) == []
    _, problems = single_problem(tmp_path, MINIMAL.replace("exponent: 0.36", "exponent: 1.34"), registry)
    assert "sane range" in problems[0]
    _, problems = single_problem(tmp_path, MINIMAL.replace("exponent: 0.36", "exponent: .nan"), registry)
    assert "finite number" in problems[0]


def test_circular_extends(tmp_path, registry):
    write(tmp_path, "a.yaml", "extends: b.yaml\n")
    write(tmp_path, "b.yaml", "description: b\nextends: a.yaml\n")
    problems = problems_of(tmp_path / "a.yaml", registry)
    assert len(problems) == 1
    assert "circular extends: a.yaml → b.yaml → a.yaml" in problems[0] and "b.yaml:2" in problems[0]
    write(tmp_path, "self.yaml", "extends: ./self.yaml\n")
    assert "circular extends: self.yaml → self.yaml" in problems_of(tmp_path / "self.yaml", registry)[0]


def test_extends_unknown_name_or_file(tmp_path, registry):
    _, problems = single_problem(tmp_path, "name: x\nextends: quadrupd\n", registry)
    assert ":2:" in problems[0] and "unknown ruleset 'quadrupd'" in problems[0] and "did you mean 'quadruped'" in problems[0]
    _, problems = single_problem(tmp_path, "extends: ../missing.yaml\n", registry)
    assert ":1:" in problems[0] and "no such file" in problems[0]


def test_problem_in_the_extended_file_points_into_that_file(tmp_path, registry):
    write(tmp_path, "parent.yaml", MINIMAL.replace("measure: length", "measure: lenth"))
    problems = problems_of(write(tmp_path, "kid.yaml", "extends: parent.yaml\n"), registry)
    assert "parent.yaml:6" in problems[0]


def test_duplicate_keys_and_rule_ids(tmp_path, registry):
    _, problems = single_problem(tmp_path, MINIMAL + "regions: [x]\n", registry)
    assert ":8:" in problems[0] and "key 'regions' is given twice (first at line 2)" in problems[0]
    doubled = MINIMAL + MINIMAL[MINIMAL.index("  - id"):]
    _, problems = single_problem(tmp_path, doubled, registry)
    assert "rule 'leg-length' is given twice" in problems[0] and ":8:" in problems[0]


def test_remove_errors(tmp_path, registry):
    _, problems = single_problem(tmp_path, "extends: quadruped\nrules:\n  - id: tail-length\n    remove: true\n", registry)
    assert ":3:" in problems[0] and "cannot remove rule 'tail-length'" in problems[0]
    _, problems = single_problem(tmp_path, "extends: quadruped\nrules:\n  - {id: head-mass, remove: true, exponent: 1}\n",
                                 registry)
    assert "takes only id and remove" in problems[0]


def test_structural_errors(tmp_path, registry):
    assert "is empty" in single_problem(tmp_path, "", registry)[1][0]
    assert "not a list" in single_problem(tmp_path, "- a\n- b\n", registry)[1][0]
    assert "names no regions" in single_problem(tmp_path, "rules: []\n", registry)[1][0]
    _, problems = single_problem(tmp_path, "regions: [a]\nrules:\n  - id: r\n    region: a\n", registry)
    assert ":3:" in problems[0] and "missing 'measure', 'exponent'" in problems[0]
    _, problems = single_problem(tmp_path, "regions: [a]\nrules:\n  - {id: r, measure: length, exponent: 0.3}\n", registry)
    assert "measure 'length' needs a region" in problems[0]
    _, problems = single_problem(tmp_path, "regions: [a]\nrules:\n  - {id: r, region: a, measure: stress, exponent: 0}\n",
                                 registry)
    assert "taken on the whole body" in problems[0]
    _, problems = single_problem(tmp_path, "regions: [a]\nrules:\n  - {region: a, measure: mass, exponent: 1}\n", registry)
    assert "rule number 1 is missing 'id'" in problems[0] and ":3:" in problems[0]
    _, problems = single_problem(tmp_path, "regions: [a]\nbody_mass: {measure: length}\n", registry)
    assert "measures length, not mass" in problems[0]
    _, problems = single_problem(tmp_path, "regions: [a]\n1: x\n", registry)
    assert "keys must be text" in problems[0] and ":2:" in problems[0]
    (tmp_path / "binary.yaml").write_bytes(b"\xff\xfe\x00bad")
    assert "not UTF-8" in problems_of(tmp_path / "binary.yaml", registry)[0]


def test_solver_errors(tmp_path, registry):
    cases = {
        "solver: {scale_bounds: [2, 0.5]}": "lower < upper",
        "solver: {scale_bounds: [1.1, 2]}": "0 < lower <= 1 <= upper",
        "solver: {alpha_bounds: [0.1, 1]}": "must contain 0",
        "solver: {scale_bounds: [1]}": "exactly two numbers",
        "solver: {step_ratio_up: 0.9}": "step_ratio_up must be greater than 1",
        "solver: {step_ratio_down: 1.2}": "less than 1",
        "solver: {algorithm: LN_FANCY}": "not an nlopt algorithm",
        "solver: {algorithm: LD_MMA}": "not a derivative-free nlopt algorithm",
        "solver: {relative_tolerance: 0}": "greater than 0",
        "solver: {transform: per-vertex}": "per-mode",
        "solver: {posture: standing}": "posture",
        "solver: {trunk_stretch: sometimes}": "solver.trunk_stretch 'sometimes' is not one of 'when-needed', 'on', 'off'",
        "solver: {trunk_hold: always}": "solver.trunk_hold 'always' is not one of 'when-needed', 'on', 'off'",
        "solver: {limb_thickness: thick}": "solver.limb_thickness 'thick' is not one of 'off', 'when-needed', 'on'",
        "solver: {ruled_shape: keep}": "solver.ruled_shape 'keep' is not one of",
    }
    for line, message in cases.items():
        _, problems = single_problem(tmp_path, MINIMAL + line + "\n", registry)
        assert message in problems[0] and ":8" in problems[0], (line, problems)


def test_transform_form_and_posture_are_the_methods_unless_the_ruleset_says(tmp_path, registry):
    solver = load_ruleset("quadruped", registry).solver
    assert (solver.transform, solver.posture) == ("per-axis", "keep")
    ruleset = load_ruleset(write(tmp_path, "axis.yaml", MINIMAL + "solver: {transform: per-mode, posture: free}\n"), registry)
    assert (ruleset.solver.transform, ruleset.solver.posture) == ("per-mode", "free")
    ruleset = load_ruleset(write(tmp_path, "upright.yaml", MINIMAL + "solver: {posture: upright}\n"), registry)
    assert ruleset.solver.posture == "upright"
    assert solver.trunk_stretch == "when-needed"
    for written, meant in (("'off'", "off"), ("off", "off"), ("on", "on"), ("when-needed", "when-needed")):
        ruleset = load_ruleset(write(tmp_path, "trunk.yaml", MINIMAL + f"solver: {{trunk_stretch: {written}}}\n"), registry)
        assert ruleset.solver.trunk_stretch == meant
        ruleset = load_ruleset(write(tmp_path, "limbs.yaml", MINIMAL + f"solver: {{limb_thickness: {written}}}\n"), registry)
        assert ruleset.solver.limb_thickness == meant
        ruleset = load_ruleset(write(tmp_path, "hold.yaml", MINIMAL + f"solver: {{trunk_hold: {written}}}\n"), registry)
        assert ruleset.solver.trunk_hold == meant
    assert solver.trunk_hold == "when-needed"


def test_numbers_without_a_dot_are_numbers(tmp_path, registry):
    ruleset = load_ruleset(write(tmp_path, "tol.yaml", MINIMAL + "solver: {relative_tolerance: 1e-7}\n"), registry)
    assert ruleset.solver.relative_tolerance == 1e-7


def test_several_problems_are_all_reported(tmp_path, registry):
    path = write(tmp_path, "many.yaml", """
        regions: [a]
        rules:
          - {id: one, region: b, measure: length, exponent: 0.3}
          - {id: two, region: a, measure: size, exponent: 0.3}
          - {id: three, region: a, measure: mass, exponent: 9}
        """)
    problems = problems_of(path, registry)
    assert len(problems) == 3
    with pytest.raises(RulesetProblems) as raised:
        load_ruleset(path, registry)
    assert "and 2 more problems" in str(raised.value) and len(raised.value.problems) == 3


def test_unknown_ruleset_name_and_missing_file(registry):
    with pytest.raises(RulesetError, match="unknown ruleset 'quadropod'.*did you mean 'quadruped'"):
        load_ruleset("quadropod", registry)
    with pytest.raises(RulesetError, match="does not exist"):
        load_ruleset("no/such/file.yaml", registry)


def test_override_exponents_errors(registry):
    ruleset = load_ruleset("neck-override", registry)
    with pytest.raises(RulesetError, match="no rule 'neck-lenght'; did you mean 'neck-length'"):
        override_exponents(ruleset, {"neck-lenght": 0.4}, registry)
    with pytest.raises(RulesetError, match="sane range"):
        override_exponents(ruleset, {"neck-length": 2.0}, registry)
    assert parse_rule_overrides(["neck-length=0.45", " head-mass = 0.8"]) == {"neck-length": 0.45, "head-mass": 0.8}
    for bad in ("neck-length", "neck-length=", "=0.3", "neck-length=tall"):
        with pytest.raises(RulesetError, match="ID=EXPONENT"):
            parse_rule_overrides([bad])


def test_load_ruleset_refuses_an_unsafe_yaml_tag(tmp_path, registry):
    _, problems = single_problem(tmp_path, "!!python/object/apply:os.system ['echo hacked']\n", registry)
    assert "YAML syntax error" in problems[0] or "YAML error" in problems[0]


# -- command line ----------------------------------------------------------------------------------
def test_cli_rulesets_lists_builtins(capsys):
    assert main(["rulesets"]) == 0
    out = capsys.readouterr().out
    for name in BUILTINS:
        assert name in out
    assert "Quadruped mammals across species" in out


def test_cli_ruleset_show_resolves_extends(capsys, tmp_path):
    assert main(["ruleset", "show", "neck-override"]) == 0
    out = capsys.readouterr().out
    assert "extends quadruped" in out
    document = yaml.safe_load(out)
    assert [rule["id"] for rule in document["rules"]][-1] == "neck-length"
    assert "foreleg-length" in [rule["id"] for rule in document["rules"]]
    assert main(["ruleset", "show", "--format", "json", "quadruped"]) == 0
    assert json.loads(capsys.readouterr().out)["name"] == "quadruped"


def test_cli_ruleset_check_exit_status_and_messages(capsys, tmp_path):
    good = write(tmp_path, "good.yaml", MINIMAL)
    assert main(["ruleset", "check", str(good)]) == 0
    assert "valid" in capsys.readouterr().out
    bad = write(tmp_path, "bad.yaml", MINIMAL.replace("legs\n", "lgs\n").replace("0.36", "7"))
    assert main(["ruleset", "check", str(bad)]) == 1
    err = capsys.readouterr().err
    assert "unknown region 'lgs'" in err and "sane range" in err and "2 problems" in err
    assert main(["ruleset", "show", str(bad)]) == 2
    assert "allorules ruleset: error:" in capsys.readouterr().err


def test_cli_ruleset_schema_prints_the_schema(capsys):
    assert main(["ruleset", "schema"]) == 0
    assert json.loads(capsys.readouterr().out) == ruleset_schema()
