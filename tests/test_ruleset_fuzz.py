"""Property-based fuzzing: no ruleset document, however broken, ends in a traceback.

Every input either loads into a :class:`Ruleset` or raises :class:`RulesetError` with a
message naming the file (and a line when one is known).
"""
from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from allorules.errors import RulesetError
from allorules.plugins.registry import registry_for
from allorules.rules.model import Ruleset
from allorules.rules.resolve import load_ruleset

REGISTRY = registry_for([], entry_points=False)

KEYS = ["name", "description", "extends", "plugins", "segmenter", "regions", "body_mass", "rules",
        "constraints", "solver", "id", "region", "measure", "exponent", "weight", "source", "remove",
        "parameters", "step_ratio_up", "step_ratio_down", "algorithm", "relative_tolerance",
        "max_evaluations", "scale_bounds", "alpha_bounds", "bogus"]
NAMES = ["head", "neck", "chest", "abdomen", "forelimbs", "hindlimbs", "tail", "mass", "length", "girth",
         "stress", "quadruped", "isometric", "terrestrial-limb-stress", "exponent", "LN_BOBYQA", "", "1x", "a/b.yaml",
         "fuzz.yaml", "./fuzz.yaml", "../x.yaml", "auto-quadruped"]

scalars = st.one_of(
    st.none(), st.booleans(), st.integers(-10**30, 10**30),
    st.floats(allow_nan=True, allow_infinity=True), st.sampled_from(NAMES), st.text(max_size=12),
)
values = st.recursive(
    scalars,
    lambda children: st.one_of(
        st.lists(children, max_size=4),
        st.dictionaries(st.one_of(st.sampled_from(KEYS), st.text(max_size=6)), children, max_size=5),
    ),
    max_leaves=20,
)


@st.composite
def near_valid_documents(draw):
    """Documents shaped like rulesets, with any field liable to be wrong."""
    document = {}
    if draw(st.booleans()):
        document["extends"] = draw(st.sampled_from(["quadruped", "neck-override", "isometric", "fuzz.yaml",
                                                    "./fuzz.yaml", "nothere", "other.yaml"]) | values)
    if draw(st.booleans()):
        document["regions"] = draw(st.lists(st.sampled_from(NAMES), max_size=7) | values)
    rule = st.fixed_dictionaries(
        {"id": st.sampled_from(["foreleg-length", "head-mass", "new-rule", "x"]) | values},
        optional={"region": st.sampled_from(NAMES) | values, "measure": st.sampled_from(NAMES) | values,
                  "exponent": st.floats(-5, 5) | values, "weight": st.floats(-1, 3) | values,
                  "remove": st.booleans() | values, "source": st.text(max_size=5)},
    )
    if draw(st.booleans()):
        document["rules"] = draw(st.lists(rule, max_size=4) | values)
    constraint = st.fixed_dictionaries(
        {"name": st.sampled_from(["terrestrial-limb-stress", "flying"]) | values},
        optional={"parameters": st.dictionaries(st.sampled_from(["exponent", "x"]), values, max_size=2) | values,
                  "weight": st.floats(-1, 3) | values, "remove": st.booleans()},
    )
    if draw(st.booleans()):
        document["constraints"] = draw(st.lists(constraint, max_size=3) | values)
    if draw(st.booleans()):
        document["solver"] = draw(st.dictionaries(
            st.sampled_from(["step_ratio_up", "step_ratio_down", "algorithm", "relative_tolerance",
                             "max_evaluations", "scale_bounds", "alpha_bounds", "nope"]),
            st.floats(-3, 3) | st.lists(st.floats(-3, 3), max_size=3) | values, max_size=4))
    if draw(st.booleans()):
        document["body_mass"] = draw(st.dictionaries(st.sampled_from(["measure", "region", "weight"]), values,
                                                     max_size=3) | values)
    if draw(st.booleans()):
        document[draw(st.sampled_from(KEYS))] = draw(values)
    return document


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    """Where the fuzzed documents are written (module-scoped: hypothesis reruns each test many times,
    and pytest removes the folder afterwards)."""
    return tmp_path_factory.mktemp("fuzz")


def assert_loads_or_reports(folder: Path, text: str) -> None:
    path = folder / "fuzz.yaml"
    path.write_text(text, encoding="utf-8")
    (folder / "other.yaml").write_text("extends: fuzz.yaml\n", encoding="utf-8")
    try:
        ruleset = load_ruleset(path, REGISTRY)
    except RulesetError as error:
        message = str(error)
        assert message and "\n" not in message.split(": ", 1)[0]
        assert "fuzz.yaml" in message or "other.yaml" in message or "unknown ruleset" in message, message
        return
    assert isinstance(ruleset, Ruleset)
    for rule in ruleset.rules:
        assert isinstance(rule.exponent, float) and rule.exponent == rule.exponent   # not NaN


FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@FUZZ
@given(near_valid_documents())
def test_near_valid_documents_never_end_in_a_traceback(folder, document):
    assert_loads_or_reports(folder, yaml.safe_dump(document, allow_unicode=True))


@FUZZ
@given(values)
@example(document="._")     # matched the float pattern's ".[0-9_]+" and crashed float("."): found by this test
def test_arbitrary_yaml_values_never_end_in_a_traceback(folder, document):
    assert_loads_or_reports(folder, yaml.safe_dump(document, allow_unicode=True))


@FUZZ
@given(st.text(alphabet=st.sampled_from(list("abx:-[]{}#&*!|>'\"%@`,?\n\t 0123456789.e")), max_size=80))
def test_arbitrary_text_never_ends_in_a_traceback(folder, text):
    assert_loads_or_reports(folder, text)


@FUZZ
@given(st.sampled_from(["quadruped", "neck-override", "isometric", "intraspecies"]), st.data())
def test_mutated_builtin_rulesets_never_end_in_a_traceback(folder, name, data):
    from allorules.rules.find import builtin_ruleset_folder

    lines = (builtin_ruleset_folder() / f"{name}.yaml").read_text(encoding="utf-8").splitlines()
    for _ in range(data.draw(st.integers(1, 3))):
        index = data.draw(st.integers(0, len(lines) - 1))
        action = data.draw(st.sampled_from(["delete", "duplicate", "indent", "dedent", "garble"]))
        if action == "delete":
            del lines[index]
        elif action == "duplicate":
            lines.insert(index, lines[index])
        elif action == "indent":
            lines[index] = "  " + lines[index]
        elif action == "dedent":
            lines[index] = lines[index][2:]
        else:
            position = data.draw(st.integers(0, len(lines[index])))
            lines[index] = lines[index][:position] + data.draw(st.text(max_size=3)) + lines[index][position:]
        if not lines:
            break
    assert_loads_or_reports(folder, "\n".join(lines) + "\n")


@pytest.mark.parametrize("text", [
    "a: &x [*x]\n",                                  # recursive alias
    "regions: &r [a]\nrules: *r\n",
    "<<: {regions: [a]}\nrules: []\n",              # merge key
    "? [a, b]\n: c\n",                                # list as key
    "regions: [a]\nrules:\n- " + "[" * 200 + "]" * 200 + "\n",   # deep nesting
    "\ufeffregions: [a]\nrules: []\n",                # byte-order mark
    "regions: [a]\nrules: []\n---\nregions: [b]\n",  # two documents
    "exponent: !!binary aGVsbG8=\n",
])
def test_awkward_yaml(folder, text):
    assert_loads_or_reports(folder, text)


def test_control_characters_are_reported_with_their_line(tmp_path):
    path = tmp_path / "control.yaml"
    path.write_text("regions: [a]\nrules: []\ndescription: bad \x1f here\n", encoding="utf-8")
    with pytest.raises(RulesetError, match=r"control.yaml:3: not readable as YAML"):
        load_ruleset(path, REGISTRY)
