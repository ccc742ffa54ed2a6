"""Biology-aware scaling runs on the generated quadruped, local scaling, and the scale CLI options.

The 1-D local experiment (Figures 12/14: the change stays inside the indicator's region without a
jump, arithmetic scaling jumps) is tested in tests/test_experiments.py; here the same comparison is
made on a mesh (:func:`seam_strain`).
"""
from __future__ import annotations

import argparse
import json
import math
import re
import textwrap

import numpy as np
import pytest

from allorules.body import Body
from allorules.errors import MeasurementError, ScalingError, SegmentationError
from allorules.measure.quality import (
    posture_warnings,
    trunk_shape_change,
    trunk_shape_warning,
)
from allorules.mesh.geometry import count_flipped_faces
from allorules.plugins.registry import registry_for
from allorules.rules.overrides import override_exponents
from allorules.rules.resolve import load_ruleset
from allorules.runs.local import scale_region, seam_strain
from allorules.runs.results import (
    CONSTRAINT_TOLERANCE,
    EXPONENT_TOLERANCE,
    MASS_TOLERANCE,
    BiologyScalingResult,
    trunk_only,
)
from allorules.runs.ruleset_run import scale_with_ruleset
from allorules.runs.steps import step_ratios
from allorules.solve.energy import cached_measure

VERTICES = 1000
MODES = 300


@pytest.fixture(autouse=True)
def _no_cache(monkeypatch):
    monkeypatch.setenv("ALLORULES_CACHE_DIR", "off")


@pytest.fixture(scope="module")
def animal():
    from allorules.mesh.quadruped import generate_quadruped

    return generate_quadruped("horse", vertices=VERTICES)


@pytest.fixture(scope="module")
def registry():
    return registry_for(None)


def _run(animal, registry, ruleset, ratio, **options):
    return scale_with_ruleset(animal.body(), ruleset, ratio, registry=registry, modes=MODES, use_cache=False, **options)


def _check_output(result, body):
    out = result.body
    assert np.array_equal(out.faces, body.faces)                      # connectivity kept
    assert np.array_equal(out.labels, body.labels)                    # labels carried along
    assert np.all(np.isfinite(out.vertices))
    assert result.flipped_faces == count_flipped_faces(body.vertices, out.vertices, body.faces)
    assert result.flipped_faces <= 0.002 * len(body.faces)
    report = result.as_dict()
    json.dumps(report, allow_nan=False)
    for key in ("mass_ratio", "stress_ratio", "steps", "converged", "rules", "step_details"):
        assert key in report
    for rule in report["rules"]:
        assert {"id", "region", "measure", "exponent", "achieved_exponent"} <= set(rule)
    for step in report["step_details"]:
        assert step["residuals"] and all(math.isfinite(value) for value in step["residuals"].values())
    # the stance of every leg is reported (the generated horse has two fore and two hind legs)
    assert sorted(report["posture"]) == ["forelimbs[0]", "forelimbs[1]", "hindlimbs[0]", "hindlimbs[1]"]
    for change in report["posture"].values():
        assert 0.0 <= change["tilt_degrees"] < 90.0 and math.isfinite(change["foot_lift"]) and math.isfinite(change["bend"])
    assert set(posture_warnings(report["posture"])) <= set(report["warnings"])
    # the section named is the one carrying the input's peak stress (it named the gauge's first band)
    from allorules.measure.stress import load_bearing_section

    peak = load_bearing_section(body)
    assert (report["section"]["region"], report["section"]["fraction"]) == (peak.region, round(peak.section.fraction, 4))
    # beyond those, only an open region's note and the trunk's shape, measured on the output itself
    assert result.trunk_shape == pytest.approx(trunk_shape_change(body, out.vertices))
    said = set(posture_warnings(report["posture"])) | {trunk_shape_warning(result.trunk_shape)}
    assert all(warning.startswith("open region") for warning in set(report["warnings"]) - said)


@pytest.mark.slow
@pytest.mark.parametrize("ratio", [2.0, 0.5])
def test_quadruped_ruleset_meets_every_target(animal, registry, ratio):
    ruleset = load_ruleset("quadruped", registry)
    result = _run(animal, registry, ruleset, ratio)
    assert result.converged, result.messages
    assert len(result.steps) == len(step_ratios(ratio))
    for rule in result.rules:
        assert abs(rule.achieved_exponent - rule.exponent) <= 0.02, rule
    assert result.mass_ratio == pytest.approx(ratio, rel=0.01)
    assert result.stress_ratio == pytest.approx(1.0, abs=0.02)
    # posture keep (the default): legs upright and every foot on the ground (upright only, the
    # hind feet rose 20 % of a leg at R = 2)
    for limb, change in result.posture.items():
        assert change["tilt_degrees"] < 1.0 and abs(change["foot_lift"]) < 0.02, (limb, change)
    # the reported figures are what an independent measurement of the output gives
    body = animal.body()
    out = body.with_vertices(result.body.vertices.copy())          # same labels and frame, nothing cached
    for rule in ruleset.rules:
        spec = registry.measure(rule.measure)
        achieved = math.log(spec.compute(out, rule.region) / spec.compute(body, rule.region)) / math.log(ratio)
        reported = next(outcome for outcome in result.rules if outcome.id == rule.id)
        assert achieved == pytest.approx(reported.achieved_exponent, abs=1e-9)
    _check_output(result, body)


@pytest.mark.slow
def test_the_last_step_is_solved_again_for_what_its_output_misses(animal, registry, monkeypatch):
    """No step after the last carries its miss forward: what the last step's output misses once
    settled (legs turned back, feet and held parts put back; here a deliberate 1 % swell of the
    whole body on the last step, as the donkey's leg turn added 0.8 % to its abdomen) is met by
    solving that step again with its targets moved by the miss. Without the refits the run misses."""
    from allorules.runs import ruleset_run

    settled = ruleset_run._settled

    def swollen(start, solution, posture, last, held, isometric):
        body = settled(start, solution, posture, last, held, isometric)
        if not last:
            return body
        centre = body.vertices.mean(axis=0)
        return body.with_vertices(centre + 1.01 * (body.vertices - centre))

    monkeypatch.setattr(ruleset_run, "_settled", swollen)
    ruleset = load_ruleset("quadruped", registry)
    result = _run(animal, registry, ruleset, 2.0)
    assert result.converged, result.messages
    assert result.mass_ratio == pytest.approx(2.0, rel=0.005)
    monkeypatch.setattr(ruleset_run, "LAST_STEP_REFITS", 0)
    unrefitted = _run(animal, registry, ruleset, 2.0)
    assert not unrefitted.converged and unrefitted.mass_ratio > 2.04


def test_a_last_step_refit_that_cannot_be_measured_keeps_the_steps_solution(animal, registry, monkeypatch):
    """The last step solved again for its output's misses may land where a measure fails (the bull
    386 at ×0.5: its refit's chest had no closed section behind the forelimbs, and the command
    ended with that one line, no report, where the step's own solution was measured and
    reported). Such a refit is not kept: the run ends on the step's solution, and says so."""
    from allorules.errors import MeasurementError
    from allorules.runs import ruleset_run

    settled = ruleset_run._settled
    lasts = []

    def swollen(start, solution, posture, last, held, isometric):
        body = settled(start, solution, posture, last, held, isometric)
        if not last:
            return body
        lasts.append(1)
        if len(lasts) > 1:      # the refit's output
            raise MeasurementError("no closed section around the chest behind the forelimbs")
        centre = body.vertices.mean(axis=0)
        return body.with_vertices(centre + 1.01 * (body.vertices - centre))

    monkeypatch.setattr(ruleset_run, "_settled", swollen)
    result = _run(animal, registry, load_ruleset("quadruped", registry), 1.21)
    assert len(lasts) == 2                                     # the refit was made, and not kept
    assert result.mass_ratio == pytest.approx(1.21 * 1.01 ** 3, rel=0.005)   # the swollen step's output
    assert len(result.steps) == 2


def test_a_step_whose_output_cannot_be_measured_stops_the_run_with_its_report(animal, registry,
                                                                            second_output_unmeasurable):
    """A step's output that a measure fails on ends the run as a step that cannot be solved does:
    a ScalingError naming the step, whose ``closest`` is the run judged on the last output measured
    (the command writes its report), not a bare measuring error with nothing written."""
    with pytest.raises(ScalingError, match="step 2 of 2: its output could not be measured: no closed section") as caught:
        _run(animal, registry, load_ruleset("quadruped", registry), 1.21)
    closest = caught.value.closest
    assert isinstance(closest, BiologyScalingResult) and not closest.converged
    assert len(closest.steps) == 1 and closest.messages[0].startswith("step 2 of 2")
    assert closest.mass_ratio == pytest.approx(1.1, rel=0.01)   # judged on step 1's output


def test_a_step_output_unmeasurable_only_at_the_next_step_stops_the_run_with_its_report(animal, registry, monkeypatch):
    """A step's output is measured for its mass and stress when it is made, and for every term only
    at the next step's start (the donkey 385 sitting at ×0.5 lost its chest's tape there): the run
    ends naming that step, judged on its start, with its report; not a bare measuring error."""
    from allorules.runs import ruleset_run

    carried, calls = ruleset_run._carried_misses, []

    def failing(terms, anchors, reached, current, measure):
        calls.append(1)
        if len(calls) == 2:                 # the second step's start: the first step's output
            raise MeasurementError("no closed section around the chest behind the forelimbs")
        return carried(terms, anchors, reached, current, measure)

    monkeypatch.setattr(ruleset_run, "_carried_misses", failing)
    with pytest.raises(ScalingError, match="step 1 of 2: its output could not be measured: no closed section") as caught:
        _run(animal, registry, load_ruleset("quadruped", registry), 1.21)
    closest = caught.value.closest
    assert isinstance(closest, BiologyScalingResult) and not closest.converged
    assert closest.messages[0].startswith("step 1 of 2")
    assert closest.mass_ratio == pytest.approx(1.0, abs=1e-9)     # judged on the first step's start


@pytest.mark.heavy
def test_a_stretched_run_reports_its_trunk_and_is_refused_beyond_the_tolerance(animal, registry, monkeypatch):
    """solver.trunk_stretch: on adds δ to every step; the run's verdict checks the trunk's length
    exponent (a trunk drawn out beyond 1/3 ± TRUNK_LENGTH_TOLERANCE is not converged, as the
    donkey's 1.43 with every rule met)."""
    from dataclasses import replace

    from allorules.runs import ruleset_run

    # with the paper's variables and δ (with κ too, δ drifts on this animal: trunk 0.139, refused)
    quadruped = load_ruleset("quadruped", registry)
    quadruped = replace(quadruped, solver=replace(quadruped.solver, limb_thickness="off"))
    stretched = replace(quadruped, solver=replace(quadruped.solver, trunk_stretch="on"))
    result = _run(animal, registry, stretched, 2.0)
    assert result.converged, result.messages
    assert all(step.trunk_stretch is not None for step in result.steps)
    assert abs(result.trunk_length_exponent - 1 / 3) <= ruleset_run.TRUNK_LENGTH_TOLERANCE
    assert result.as_dict()["trunk_length_exponent"] == result.trunk_length_exponent
    plain = _run(animal, registry, quadruped, 2.0)             # every run's trunk is checked
    assert plain.converged and all(step.trunk_stretch is None for step in plain.steps)
    assert abs(plain.trunk_length_exponent - 1 / 3) <= ruleset_run.TRUNK_LENGTH_TOLERANCE
    monkeypatch.setattr(ruleset_run, "TRUNK_LENGTH_TOLERANCE", abs(result.trunk_length_exponent - 1 / 3) / 2)
    refused = _run(animal, registry, stretched, 2.0)
    assert not refused.converged and any("trunk's length reached exponent" in message for message in refused.messages)


def test_the_trunks_verdict_says_where_the_rules_leave_the_mass(animal, registry):
    """The head and abdomen lighter than isometric at ×2 (M^0.70, M^0.74) and the open regions
    isometric leave the chest and legs more than ×2 of their mass, less than ×0.5 at ×0.5; an
    isometric ruleset leaves them exactly R, and the verdict says nothing."""
    from allorules.measure.mass import body_mass, region_mass
    from allorules.runs.ruleset_run import mass_left

    body = animal.body()
    quadruped = load_ruleset("quadruped", registry)
    shares = {name: region_mass(body, name) / body_mass(body) for name in body.region_names}
    expected = (2.0 - shares["head"] * 2 ** 0.7 - shares["abdomen"] * 2 ** 0.74 - (shares["neck"] + shares["tail"]) * 2) \
        / (shares["chest"] + shares["forelimbs"] + shares["hindlimbs"])
    grown = mass_left(quadruped, body, 2.0)
    assert f"×{expected:.2f} in mass where the body changes ×2" in grown and expected > 2.1, grown
    assert f"the head, {100 * shares['head']:.0f} % of the body, at M^0.70" in grown and "the neck and tail isometric" in grown
    shrunk = float(re.search(r"×([0-9.]+) in mass", mass_left(quadruped, body, 0.5)).group(1))
    assert shrunk < 0.5
    assert mass_left(load_ruleset("isometric", registry), body, 2.0) == ""



def test_a_refusal_says_which_mass_rules_strain_the_body_and_how_to_ease_them(animal, registry):
    """A run refused other than by its trunk, whose mass rules leave the rest of the body far from
    the ratio (a cartoon's big head and belly at ×0.5: its chest and legs ×0.35, and the chest
    folds), says so and names each mass rule to hold isometric; the trunk's refusal keeps its own
    settling, followed by that one where the budget explains it too; a converged run none."""
    from allorules.runs.results import RuleOutcome
    from allorules.runs.ruleset_run import mass_budget

    body = animal.body()
    budget = mass_budget(load_ruleset("quadruped", registry), body, 0.5)
    assert budget is not None and budget.startswith("the rules leave the chest, forelimbs and hindlimbs ×")
    rules = [RuleOutcome("head-mass", "head", "mass", 0.70, 1.0, 0.6, 0.5),
             RuleOutcome("abdomen-mass", "abdomen", "mass", 0.74, 1.0, 0.6, 0.74),
             RuleOutcome("chest-girth", "chest", "girth", 0.365, 1.0, 0.8, 0.365)]
    refused = BiologyScalingResult(body, 0.5, ruleset="quadruped", rules=rules, missed=("rule",), mass_budget=budget)
    settle = refused.settle()
    assert settle.startswith(budget) and settle == refused.as_dict()["settle"]
    assert "--rule head-mass=1 --rule abdomen-mass=1" in settle
    assert "--ruleset cartoon" in settle            # quadruped's own: the built-in ruleset that holds them
    own = BiologyScalingResult(body, 0.5, ruleset="my-set.yaml", rules=rules, missed=("rule",), mass_budget=budget)
    assert "--rule head-mass=1 --rule abdomen-mass=1" in own.settle() and "--ruleset cartoon" not in own.settle()
    assert "chest-girth" not in settle
    converged = BiologyScalingResult(body, 0.5, ruleset="quadruped", rules=rules, converged=True, mass_budget=budget)
    assert converged.settle() is None
    trunk = BiologyScalingResult(body, 0.5, ruleset="quadruped", rules=rules, missed=("trunk",),
                                 trunk_length_exponent=0.5)
    assert trunk.settle() == trunk.settle_trunk() and "trunk-length" in trunk.settle()
    # a trunk-only miss the budget explains (a faceted bison at ×2, its chest and legs left ×3.5):
    # the trunk's rule, or the mass rules held isometric; the budget itself is in the trunk's verdict
    strained = BiologyScalingResult(body, 0.5, ruleset="quadruped", rules=rules, missed=("trunk",),
                                    trunk_length_exponent=0.5, mass_budget=budget)
    both = strained.settle()
    assert both.startswith(strained.settle_trunk() + "; or, ") and "--ruleset cartoon" in both
    assert budget not in both
    # a trunk drawn out and a distorted output: the budget, in the trunk's verdict, is said once
    verdict = f"the trunk's length reached exponent 0.498, beyond 0.333 ± 0.1: stretched ({budget})"
    distorted = BiologyScalingResult(body, 2.0, ruleset="quadruped", rules=rules, missed=("trunk", "distorted"),
                                     trunk_length_exponent=0.498, mass_budget=budget, messages=[verdict])
    said = distorted.settle()
    assert budget not in said and said.startswith("If its head or abdomen") and "--ruleset cartoon" in said
    # the verdict second (a leg missed first): the refusal's line shows the first alone, so the budget is said
    behind = BiologyScalingResult(body, 2.0, ruleset="quadruped", rules=rules, missed=("rule", "trunk"),
                                  trunk_length_exponent=0.498, mass_budget=budget,
                                  messages=["rule 'hindleg-length' reached exponent 0.371, target 0.336", verdict])
    assert behind.settle().startswith(budget + "; if its head or abdomen")

@pytest.mark.heavy
def test_a_trunk_that_no_rule_lengthens_must_stay_isometric(animal, registry, monkeypatch, tmp_path):
    """Without the trunk's stretch Eq. 9 can still draw the trunk out: the bull 386 at x2 met every
    rule with its trunk's length at exponent 0.6. Unless a rule measures a torso region's length, a
    trunk beyond 1/3 ± TRUNK_LENGTH_TOLERANCE is not converged."""
    from allorules.runs import ruleset_run

    quadruped = load_ruleset("quadruped", registry)
    plain = _run(animal, registry, quadruped, 2.0)
    assert plain.converged
    monkeypatch.setattr(ruleset_run, "TRUNK_LENGTH_TOLERANCE", abs(plain.trunk_length_exponent - 1 / 3) / 2)
    refused = _run(animal, registry, quadruped, 2.0)
    assert not refused.converged
    assert any("no rule asks for it" in message for message in refused.messages), refused.messages
    assert any("the rules leave the chest, forelimbs and hindlimbs ×" in message for message in refused.messages)
    assert refused.missed == ("trunk",) and refused.as_dict()["missed"] == ["trunk"]     # what the retries read
    assert plain.missed == () and plain.settle_trunk() is None
    # the refusal says how to accept that trunk: a rule on it, which then converges
    settle = refused.settle_trunk()
    assert refused.as_dict()["settle"].startswith(settle) and "measure: trunk-length" in settle, settle
    exponent = float(re.search(r"exponent: ([0-9.]+)\}", settle).group(1))
    assert exponent == pytest.approx(plain.trunk_length_exponent, abs=0.006)
    path = tmp_path / "long-trunk.yaml"
    path.write_text(f"name: long-trunk\ndescription: as the refusal says\nextends: quadruped\nrules:\n"
                    f"  - {{id: trunk-length, measure: trunk-length, exponent: {exponent}}}\n", encoding="utf-8")
    accepted = _run(animal, registry, load_ruleset(str(path), registry), 2.0)
    assert accepted.converged, accepted.messages
    assert abs(next(rule for rule in accepted.rules if rule.id == "trunk-length").error) <= 0.02
    path = tmp_path / "long-chest.yaml"
    path.write_text(textwrap.dedent("""\
        name: long-chest
        description: the chest's length has its own rule
        extends: quadruped
        rules:
          - id: chest-length
            region: chest
            measure: length
            exponent: 0.36
            source: a rule on the trunk's length
        """), encoding="utf-8")
    ruled = _run(animal, registry, load_ruleset(str(path), registry), 2.0)
    assert not any("trunk's length" in message for message in ruled.messages)


@pytest.mark.parametrize("ratio, exponent, said", [(2.0, 0.6, "stretched"), (2.0, 0.1, "shortened"),
                                                   (0.5, 0.6, "shortened"), (0.5, 0.1, "stretched")])
def test_the_verdict_says_which_way_the_trunk_went(animal, registry, ratio, exponent, said):
    """At ×0.5 an exponent above 1/3 is a trunk shorter than isometric scaling makes it (the bull
    386 at ×0.5, 0.498, was once said to have come out stretched)."""
    from allorules.runs import ruleset_run

    body = animal.body()
    scaled = body.with_vertices(body.vertices * ratio ** exponent)       # trunk exponent = `exponent`
    result = BiologyScalingResult(body=scaled, target_mass_ratio=ratio)
    [message] = ruleset_run._check_trunk_length(result, body, scaled, load_ruleset("quadruped", registry), False)
    assert result.trunk_length_exponent == pytest.approx(exponent)
    assert re.search(r"the animal came out (\w+)", message).group(1) == said


def test_the_trunks_length_is_a_measure_a_rule_can_name(animal, registry, tmp_path):
    """``trunk-length`` (shoulder to buttock along the torso) is a whole-body measure: a rule on it
    says how long the trunk grows, so the verdict's check of the trunk stands aside, and the
    trunk's hold (solver.trunk_hold) has nothing to hold."""
    from allorules.measure.length import trunk_length
    from allorules.runs import ruleset_run

    body = animal.body()
    spec = registry.measure("trunk-length")
    assert spec.compute(body, None) == trunk_length(body) and spec.isometric_exponent == pytest.approx(1 / 3)
    assert not spec.accepts_region
    path = tmp_path / "long-trunk.yaml"
    path.write_text(textwrap.dedent("""\
        name: long-trunk
        description: a dachshund's trunk
        extends: quadruped
        rules:
          - id: trunk-length
            measure: trunk-length
            exponent: 0.45
            source: a breeder's wish
        """), encoding="utf-8")
    ruleset = load_ruleset(str(path), registry)
    assert ruleset_run._trunk_ruled(ruleset) and not ruleset_run._trunk_ruled(load_ruleset("quadruped", registry))
    measure = cached_measure(registry)
    assert ruleset_run._trunk_hold_term(ruleset, body, measure) is None
    term = ruleset_run._trunk_hold_term(load_ruleset("quadruped", registry), body, measure)
    assert (term.measure, term.region, term.exponent) == ("trunk-length", None, pytest.approx(1 / 3))


@pytest.mark.heavy
def test_a_converged_run_whose_trunk_strayed_is_made_again_held(animal, registry, monkeypatch):
    """A run that meets every target with its trunk's length within TRUNK_LENGTH_TOLERANCE of 1/3
    but beyond TRUNK_LENGTH_RETRY is made again with the trunk held (solver.trunk_hold), and the
    held run is kept when it converges nearer 1/3 (the real horse at ×2: 0.419, its chest rising
    into its neck; held, 0.38). Here the retry's threshold is set below this animal's own
    deviation, so that its run strays by definition."""
    from allorules.runs import pipeline

    quadruped = load_ruleset("quadruped", registry)
    quadruped = replace_solver(quadruped, limb_thickness="off")
    body = animal.body()

    def run(ruleset):
        return pipeline.scale(body, pipeline.RulesetScaling(ruleset, 2.0), registry=registry, modes=MODES,
                              use_cache=False)

    first = run(quadruped)
    assert first.converged, first.messages
    strayed = abs(first.trunk_length_exponent - 1 / 3)
    assert not any("trunk" in warning for warning in first.warnings)       # within the retry's threshold
    monkeypatch.setattr(pipeline, "TRUNK_LENGTH_RETRY", strayed / 2)
    again = run(quadruped)
    assert again.converged, again.messages
    # the held run kept (0.360 → 0.334 here), and said so
    assert abs(again.trunk_length_exponent - 1 / 3) < strayed / 2
    assert all(step.trunk_stretch is not None for step in again.steps)
    assert again.warnings[0].startswith("the run met every target with the trunk's length at exponent")
    off = run(replace_solver(quadruped, trunk_hold="off"))      # never made again where the hold is off
    assert off.trunk_length_exponent == pytest.approx(first.trunk_length_exponent)
    assert all(step.trunk_stretch is None for step in off.steps)


def test_a_held_run_that_does_no_better_keeps_the_first_and_says_so(animal, registry):
    """The choice itself, on stand-in runs: a held run is kept only if it converges with its trunk
    nearer 1/3; else the first run is kept with a warning naming its trunk; a trunk within the
    retry's threshold is not made again."""
    from allorules.runs import pipeline

    solver = load_ruleset("quadruped", registry).solver
    body = animal.body()

    def result(trunk, converged=True):
        return BiologyScalingResult(body=body, target_mass_ratio=2.0, converged=converged, trunk_length_exponent=trunk,
                                    messages=[] if converged else ["rule 'chest-girth' reached exponent 0.40"])

    calls = []

    def run_with(returned):
        def run(held_solver):
            calls.append(held_solver.trunk_hold)
            return returned
        return run

    kept = pipeline._trunk_nearer_isometric(result(0.36), solver, run_with(result(0.34)))
    assert kept.trunk_length_exponent == 0.36 and calls == []                       # within ±0.05: as it is
    kept = pipeline._trunk_nearer_isometric(result(0.42), solver, run_with(result(0.38)))
    assert kept.trunk_length_exponent == 0.38 and calls == ["on"] and "0.420" in kept.warnings[0]
    for held in (result(0.45), result(0.35, converged=False)):                      # further, or missed
        kept = pipeline._trunk_nearer_isometric(result(0.24), solver, run_with(held))
        assert kept.trunk_length_exponent == 0.24
        assert "0.240" in kept.warnings[-1] and kept.warnings[-1].endswith("the animal's trunk may look shorter")   # ×2 at 0.24


def test_a_held_run_whose_trunk_humps_keeps_the_first(animal, registry):
    """A held run nearer 1/3 is still not kept where its trunk is humped beyond the warning's level
    and by more than TRUNK_SHAPE_SLACK over the first run's (the real horse at ×0.5: held 0.37, first
    0.30, its back sagged and rump raised); within the slack, below the warning (the wolf: 0.22 held,
    0.16 first), or where a shape is unmeasured, it is kept."""
    from allorules.runs import pipeline

    solver = load_ruleset("quadruped", registry).solver
    body = animal.body()

    def result(trunk, shape):
        return BiologyScalingResult(body=body, target_mass_ratio=0.5, converged=True, trunk_length_exponent=trunk,
                                    trunk_shape=shape)

    for first_shape, held_shape, held_kept in ((0.30, 0.37, False), (0.30, 0.30 + 0.9 * pipeline.TRUNK_SHAPE_SLACK, True),
                                              (0.30, 0.2, True), (0.30, None, True), (0.16, 0.22, True)):
        kept = pipeline._trunk_nearer_isometric(result(0.276, first_shape), solver,
                                                lambda _solver: result(0.335, held_shape))
        assert kept.trunk_length_exponent == (0.335 if held_kept else 0.276), held_shape
        if not held_kept:
            assert "the run as first made is kept" in kept.warnings[-1] and "37%" in kept.warnings[-1]



def test_a_run_whose_every_try_misses_is_made_again_with_a_basis_every_step(animal, registry, monkeypatch):
    """Where every try misses a rule (the donkey 385 at ×2, its heart girth), the tries are made
    again with each step on a basis of its own mesh and kept if they converge; not where the
    trunk's length is the one miss, nor where the first tries converge."""
    from allorules.runs import pipeline

    body = animal.body()
    scaling = pipeline.RulesetScaling(load_ruleset("quadruped", registry), 2.0)
    calls = []

    def stand_in(outcomes):
        def tries(_body, _scaling, *, registry, modes, use_cache, progress, basis_every=None):
            calls.append(basis_every)
            if outcomes[basis_every] is None:      # the second pass's first run stops
                raise ScalingError("step 6 of 8 could not be solved: volume of region 'horns' cannot be determined")
            converged, missed = outcomes[basis_every]
            return BiologyScalingResult(body=body, target_mass_ratio=2.0, converged=converged, missed=missed,
                                        messages=[] if converged else [f"missed ({basis_every})"])
        return tries

    def scale(outcomes):
        calls.clear()
        monkeypatch.setattr(pipeline, "_ruleset_tries", stand_in(outcomes))
        return pipeline._scale_with_ruleset(body, scaling, registry=registry, modes=None, use_cache=False,
                                            progress=None)

    rule_miss, trunk_miss, met = (False, ("rule",)), (False, ("trunk",)), (True, ())
    kept = scale({None: rule_miss, 1: met})
    assert calls == [None, 1] and kept.converged and "a basis of its own mesh" in kept.warnings[0]
    kept = scale({None: rule_miss, 1: rule_miss})
    assert calls == [None, 1] and not kept.converged and kept.messages == ["missed (None)"]
    assert "did not converge either (missed (1))" in kept.warnings[-1]
    kept = scale({None: rule_miss, 1: None})                   # stopped: one more miss, the first run stands
    assert calls == [None, 1] and not kept.converged and "could not be solved" in kept.warnings[-1]
    for first in (met, trunk_miss):
        kept = scale({None: first, 1: met})
        assert calls == [None] and kept.converged == first[0]


def replace_solver(ruleset, **settings):
    from dataclasses import replace

    return replace(ruleset, solver=replace(ruleset.solver, **settings))


@pytest.mark.slow
def test_the_trunk_held_isometric_brings_a_drawn_out_trunk_back(animal, registry):
    """With δ free (κ and δ on) the generated horse at ×2 meets every rule with its trunk drawn in
    to exponent 0.210, refused; held by the soft term of solver.trunk_hold, δ brings it to 0.333
    with every rule still met."""
    from dataclasses import replace

    quadruped = load_ruleset("quadruped", registry)
    free = replace(quadruped, solver=replace(quadruped.solver, trunk_stretch="on", limb_thickness="on"))
    held = replace(free, solver=replace(free.solver, trunk_hold="on"))
    loose, kept = _run(animal, registry, free, 2.0), _run(animal, registry, held, 2.0)
    assert all(step.trunk_stretch is not None for step in kept.steps)
    assert abs(kept.trunk_length_exponent - 1 / 3) < 0.5 * abs(loose.trunk_length_exponent - 1 / 3)
    assert abs(kept.trunk_length_exponent - 1 / 3) <= 0.02
    assert kept.converged, kept.messages


def test_isometric_ruleset_is_uniform_scaling(animal, registry):
    from progress_recorder import RecordingProgress

    progress = RecordingProgress()
    result = _run(animal, registry, load_ruleset("isometric", registry), 2.0, progress=progress)
    assert len(result.steps) == 8
    progress.check(8, [step.evaluations for step in result.steps])
    body = animal.body()
    from allorules.mesh.geometry import vertex_areas

    weights = vertex_areas(body.vertices, body.faces)
    centre = weights @ body.vertices / weights.sum()
    np.testing.assert_allclose(result.body.vertices, centre + 2.0 ** (1 / 3) * (body.vertices - centre),
                               atol=1e-6 * np.ptp(body.vertices))
    assert all(step.evaluations == 1 for step in result.steps)       # the start is already the answer
    assert result.mass_ratio == pytest.approx(2.0, rel=1e-9)
    for rule in result.rules:
        assert rule.achieved_exponent == pytest.approx(rule.exponent, abs=1e-6)
    _check_output(result, body)


def test_neck_length_measure_does_not_depend_on_place(animal):
    from allorules.measure.length import region_length

    body = animal.body()
    moved = body.with_vertices(body.vertices + np.array([5.0, 0.0, 0.0]))
    assert region_length(moved, "neck") == pytest.approx(region_length(body, "neck"), rel=1e-6)


@pytest.mark.slow
def test_neck_override_moves_the_neck_exponent(animal, registry):
    ruleset = override_exponents(load_ruleset("neck-override", registry), {"neck-length": 0.55}, registry)
    ratio = 1.1 ** 3
    result = _run(animal, registry, ruleset, ratio)
    assert result.converged, result.messages
    neck = next(rule for rule in result.rules if rule.id == "neck-length")
    assert neck.exponent == 0.55
    assert neck.achieved_exponent == pytest.approx(0.55, abs=EXPONENT_TOLERANCE)
    assert len(result.steps) == 3


@pytest.mark.parametrize("growths, kept", [((1.01, 1.01, 1.01), True), ((1.01, 1.01, 1.03, 1.01, 1.03), False)])
def test_a_turn_back_that_moves_a_target_is_solved_for_or_left_out(animal, registry, monkeypatch, growths, kept):
    """The neck and the head turned back at the run's end move the measures a little (the cartoon
    cow Spot's, turned 15° at ×0.5, by 1.6× a tolerance): a turn that moves a target beyond its
    tolerance is tried with the head alone, then has the last step solved once more for what it
    moved. Stood in for by a "turn" that grows the whole body (its mass 3 % over, the tolerance
    1 %): by 1.01 every time (the head alone no better), the step solved again meets the mass on
    the grown body; by 1.03 after it is solved again, it cannot, and neither can the neck bent back
    along its length (1.01, then 1.03 after its own refit): the output is left unturned, every
    target met, a warning saying so."""
    from allorules.runs import ruleset_run
    from allorules.solve.held_regions import HeldRegions

    factors = list(growths)

    def growing(self, vertices, neck=True, faces=None):
        vertices = np.asarray(vertices, dtype=float)
        centre = vertices.mean(axis=0)
        return centre + (factors.pop(0) if factors else 1.0) * (vertices - centre)

    monkeypatch.setattr(HeldRegions, "turned_back", growing)
    # the growth moves the open regions held isometric too (no refit can take that back); they are
    # judged in the test below
    monkeypatch.setattr(ruleset_run, "_worst_open_region", lambda *args: 0.0)
    result = _run(animal, registry, load_ruleset("quadruped", registry), 2.0)
    assert not factors           # turned, the head alone, solved again and turned again (and, missing, bent twice)
    assert result.converged, result.messages
    assert abs(result.mass_ratio / 2.0 - 1.0) <= 0.01
    left = [warning for warning in result.warnings if "left turned as Eq. 9 turned them" in warning]
    assert (not left) if kept else ("solved again too" in left[0])


def test_a_turn_back_that_misses_at_the_neck_base_and_head_alone_bends_the_neck_along_its_length(
        animal, registry, monkeypatch):
    """Where the neck turned back at its base and the head alone both miss (the held-out goat at
    ×0.5, its neck 19 vertices: 1.1× a tolerance), the neck bent back along its length is tried
    (its miss 0.5×) and kept. Stood in for by a "turn" that grows the body 3 % in mass turned at the
    base or the head alone (and 9 % once the step is solved again for it), and moves nothing bent:
    the bent output is kept, no warning."""
    from allorules.runs import ruleset_run
    from allorules.solve.held_regions import HeldRegions

    asked, factors = [], [1.01, 1.01, 1.03]

    def turning(self, vertices, neck=True, faces=None):
        asked.append((neck, faces is not None))
        vertices = np.array(vertices, dtype=float)
        if faces is not None:
            return vertices
        centre = vertices.mean(axis=0)
        return centre + (factors.pop(0) if factors else 1.03) * (vertices - centre)

    monkeypatch.setattr(HeldRegions, "turned_back", turning)
    monkeypatch.setattr(ruleset_run, "_worst_open_region", lambda *args: 0.0)
    result = _run(animal, registry, load_ruleset("quadruped", registry), 2.0)
    assert asked[:4] == [(True, False), (False, False), (True, False), (True, True)]
    assert result.converged, result.messages
    assert not [warning for warning in result.warnings if "left turned" in warning]


def test_a_neck_that_its_turn_back_lengthens_stays_and_the_head_alone_turns(animal, registry, monkeypatch):
    """A neck as short as it is wide bends its whole length at its base as it is turned back (the
    low-poly dog's read 6 % longer at ×2: its length exponent 0.377 for the 0.333 ± 0.02 it is held
    at). Stood in for by a "turn" that stretches the neck 6 % along the body and turns nothing when
    asked to turn the head alone: the head alone is turned, and the neck stays isometric, no
    warning (nor is the neck bent back along its length)."""
    from allorules.solve.held_regions import HeldRegions

    neck = animal.body().labels == list(animal.body().region_names).index("neck")
    asked = []

    def turning(self, vertices, neck_too=True, faces=None):
        asked.append((neck_too, faces is not None))
        vertices = np.array(vertices, dtype=float)
        if neck_too:
            centre = vertices[neck].mean(axis=0)
            vertices[neck, 0] = centre[0] + 1.06 * (vertices[neck, 0] - centre[0])
        return vertices

    monkeypatch.setattr(HeldRegions, "turned_back", turning)
    result = _run(animal, registry, load_ruleset("quadruped", registry), 2.0)
    assert asked[:2] == [(True, False), (False, False)] and (True, True) not in asked
    assert result.converged, result.messages
    held = [outcome for outcome in result.open_regions if outcome.region == "neck" and outcome.held]
    assert held and all(outcome.met for outcome in held)
    assert not [warning for warning in result.warnings if "left turned" in warning]


def test_a_turn_back_that_distorts_a_feature_is_left_out(animal, registry, monkeypatch):
    """The bull 386's ear, on its head's base, was sheared as its head turned back at ×0.5 (changed
    shape by 31 % of its size, beyond the 25 % that refuses a run), and its run went on to retries
    that failed. Stood in for by a "turn" whose output (every way: with the neck, the head alone,
    and the neck bent along its length) is reported distorted: the output is left unturned,
    converged, a warning saying why."""
    from allorules.runs import ruleset_run
    from allorules.solve.held_regions import HeldRegions

    turned = []

    def turning(self, vertices, neck=True, faces=None):
        vertices = np.array(vertices, dtype=float)
        vertices[0] += 1e-9 * np.ptp(vertices)        # told apart from the output it turned
        turned.append(vertices)
        return vertices

    real = ruleset_run.distortions

    def distortions(before, after):
        if any(np.array_equal(after, other) for other in turned):
            return ["a small feature changed shape by 31% of its size (limit 25%)"]
        return real(before, after)

    monkeypatch.setattr(HeldRegions, "turned_back", turning)
    monkeypatch.setattr(ruleset_run, "distortions", distortions)
    result = _run(animal, registry, load_ruleset("quadruped", registry), 2.0)
    assert len(turned) == 3                              # with the neck, the head alone, bent; no refit
    assert result.converged, result.messages
    left = [warning for warning in result.warnings if "left turned as Eq. 9 turned them" in warning]
    assert left and "looked distorted" in left[0]


def test_a_turn_back_that_turns_the_head_further_is_not_a_turn_back():
    """The held-out low-poly goat at ×2 (its neck 19 vertices, its head 47, most of both the bases
    that bend): the parts' best similarities, fitted on so few, turned its head from 5.4° to 8.1°
    as they were turned back. A candidate whose head ends further from the input's direction than
    Eq. 9 left it, by more than TURN_SLACK and beyond TURN_SEEN, is judged worse than any miss;
    within either, it is judged on its misses alone (a neck straightened, its head 0.5° → 1.8°)."""
    from allorules.runs.ruleset_run import TURN_SEEN, TURN_SLACK, _TurnMisses

    unturned = _TurnMisses(0.4, 0.3, 0, {}, 5.4)
    further = unturned._replace(head_turn=8.1)
    assert further.turned_further(unturned) and further.worst(unturned) == math.inf
    assert "turned the head further (8.1°" in further.missing(unturned)
    back = unturned._replace(head_turn=0.2)
    assert not back.turned_further(unturned) and back.worst(unturned) == back.score
    assert not unturned._replace(head_turn=5.4 + 0.9 * TURN_SLACK).turned_further(unturned)
    straight = _TurnMisses(0.4, 0.3, 0, {}, 0.5)
    assert not straight._replace(head_turn=0.9 * TURN_SEEN).turned_further(straight)
    assert straight._replace(head_turn=1.1 * TURN_SEEN).turned_further(straight)
    assert not _TurnMisses(0.4, 0.3, 0, {}, None)._replace(head_turn=30.0).turned_further(
        _TurnMisses(0.4, 0.3, 0, {}, None))      # no head: nothing to judge


def _contradictory_ruleset(tmp_path, registry):
    path = tmp_path / "contradiction.yaml"
    path.write_text(textwrap.dedent("""\
        name: contradiction
        description: two rules on the same quantity that cannot both hold
        extends: quadruped
        rules:
          - id: foreleg-length-again
            region: forelimbs
            measure: length
            exponent: 1.0
            source: deliberately impossible
        solver:
          max_evaluations: 40
        """), encoding="utf-8")
    return path


def test_unreachable_target_is_reported_not_hidden(animal, registry, tmp_path):
    ruleset = load_ruleset(_contradictory_ruleset(tmp_path, registry), registry)
    result = _run(animal, registry, ruleset, 1.1)
    assert result.converged is False
    assert any("foreleg-length" in message for message in result.messages)
    assert "not converged" in result.messages[-1]
    outcomes = {rule.id: rule for rule in result.rules}
    # the least-squares compromise lies between the two targets, far from both
    assert abs(outcomes["foreleg-length"].error) > EXPONENT_TOLERANCE
    assert abs(outcomes["foreleg-length-again"].error) > EXPONENT_TOLERANCE
    assert result.as_dict()["converged"] is False
    # at ×1.1 the head's and abdomen's rules leave the rest within 5 % of isometric: nothing to ease
    assert result.mass_budget is None and result.settle() is None and result.as_dict()["settle"] is None


def test_a_refusal_that_missed_its_trunk_and_more_says_where_the_mass_went(animal, registry, tmp_path, monkeypatch):
    """A run that missed its rules and its trunk (a cartoon kitten at ×2) says where its rules leave
    the mass in the refusal's line (``settle``); only a trunk-only miss is settled by a trunk rule."""
    from allorules.runs import ruleset_run

    monkeypatch.setattr(ruleset_run, "mass_budget", lambda ruleset, body, ratio: "the rules leave the chest ×2.5")
    monkeypatch.setattr(ruleset_run, "_check_trunk_length", lambda *arguments: ["the trunk's length strayed"])
    ruleset = load_ruleset(_contradictory_ruleset(tmp_path, registry), registry)
    result = _run(animal, registry, ruleset, 1.1)
    assert not result.converged and "trunk" in result.missed and "rule" in result.missed
    assert result.settle().startswith("the rules leave the chest ×2.5; if its head or abdomen")


def test_missing_regions_are_refused(animal, registry):
    body = animal.body()
    unlabelled = Body(body.vertices, body.faces)
    with pytest.raises(SegmentationError, match="needs region"):
        scale_with_ruleset(unlabelled, load_ruleset("quadruped", registry), 2.0, registry=registry, modes=MODES)
    with pytest.raises(ScalingError, match="mass ratio"):
        scale_with_ruleset(body, load_ruleset("quadruped", registry), -1.0, registry=registry, modes=MODES)


def test_tolerances_are_the_documented_ones():
    assert (EXPONENT_TOLERANCE, MASS_TOLERANCE, CONSTRAINT_TOLERANCE) == (0.02, 0.01, 0.02)


# ---------------------------------------------------------------------------------------------
# Local scaling (Eq. 5-7) against the arithmetic variant


@pytest.fixture(scope="module")
def basis(animal):
    from allorules.spectral.basis import compute_basis

    return compute_basis(animal.vertices, animal.faces, MODES, use_cache=False)


@pytest.mark.parametrize("form", ["per-mode", "per-axis"])
def test_local_power_law_has_no_seam_arithmetic_tears(animal, basis, form):
    body = animal.body()
    assert np.array_equal(scale_region(body, "head", 0.0, basis=basis, form=form).vertices, body.vertices)
    head = body.region_mask("head")
    grown = scale_region(body, "head", -0.4, basis=basis, form=form)
    moved = np.linalg.norm(grown.vertices - body.vertices, axis=1)
    assert moved[head].mean() > 2 * moved[~head].mean()          # the change is mostly in the head
    # a comparable arithmetic edit: the head's vertices scaled by the factor its size changed by
    from allorules.measure.mass import region_mass

    factor = (region_mass(grown, "head") / region_mass(body, "head")) ** (1 / 3)
    assert factor > 1.02
    torn = scale_region(body, "head", 0.0, basis=basis, arithmetic_factor=factor)
    smooth, seam = seam_strain(body.vertices, grown.vertices, body.faces, head), seam_strain(body.vertices, torn.vertices, body.faces, head)
    assert smooth["seam"] < 2.0                        # boundary edges stretch like the rest
    assert seam["boundary"] > 5 * smooth["boundary"]   # the arithmetic variant tears at the boundary
    assert seam["seam"] > 5.0
    assert seam["inside"] == pytest.approx(factor - 1.0, rel=1e-3)   # inside, arithmetic is uniform scaling
    assert count_flipped_faces(body.vertices, grown.vertices, body.faces) == 0


def test_local_scaling_refuses_unknown_region(animal, basis):
    with pytest.raises(SegmentationError, match="no region 'tail-fin'"):
        scale_region(animal.body(), "tail-fin", 0.2, basis=basis)


# ---------------------------------------------------------------------------------------------
# The CLI options (allorules scale ... --ruleset / --region)


def _parser():
    from allorules.cli import scale

    parser = argparse.ArgumentParser()
    scale.register(parser.add_subparsers())
    return parser


@pytest.fixture(scope="module")
def mesh_files(animal, tmp_path_factory):
    folder = tmp_path_factory.mktemp("animal")
    mesh = folder / "animal.obj"
    animal.to_trimesh().export(mesh)
    labels = folder / "animal.labels.json"
    labels.write_text(json.dumps(animal.labels_document()), encoding="utf-8")
    return mesh, labels


def test_cli_local_scaling_writes_mesh_and_report(mesh_files, tmp_path, capsys):
    from allorules.cli import main

    mesh, labels = mesh_files
    out, report = tmp_path / "big-head.obj", tmp_path / "local.json"
    status = main(["scale", str(mesh), "--region", "head", "--alpha", "-0.2", "--segmentation", str(labels),
                   "--modes", str(MODES), "--no-cache", "-o", str(out), "--report", str(report)])
    assert status == 0
    assert out.exists()
    data = json.loads(report.read_text())
    assert data["mode"] == "local" and data["region"] == "head" and data["seam"]["seam"] < 2.0
    assert data["transform"] == "per-axis"
    assert "seam" in capsys.readouterr().out
    # --transform per-mode: the other form of the power law, a different mesh
    other, other_report = tmp_path / "big-head-per-mode.obj", tmp_path / "local-per-mode.json"
    assert main(["scale", str(mesh), "--region", "head", "--alpha", "-0.2", "--segmentation", str(labels), "--modes",
                 str(MODES), "--no-cache", "--transform", "per-mode", "-o", str(other), "--report", str(other_report)]) == 0
    assert json.loads(other_report.read_text())["transform"] == "per-mode"
    import trimesh

    assert not np.allclose(trimesh.load(other, process=False).vertices, trimesh.load(out, process=False).vertices)


def test_cli_posture_overrides_the_ruleset(mesh_files, tmp_path, capsys):
    from allorules.cli import main

    mesh, labels = mesh_files
    reports = {}
    for posture in ("free", "keep"):
        out, report = tmp_path / f"{posture}.obj", tmp_path / f"{posture}.json"
        assert main(["scale", str(mesh), "--ruleset", "quadruped", "--mass-ratio", "1.1", "--segmentation", str(labels),
                     "--modes", str(MODES), "--no-cache", "--posture", posture, "-o", str(out), "--report", str(report)]) == 0
        reports[posture] = json.loads(report.read_text())
        assert reports[posture]["posture_setting"] == posture
        # the terminal's last figures are the report's: lean, foot lift and bow
        bend = max(change["bend"] for change in reports[posture]["posture"].values())
        assert f"bow added up to {100 * bend:+.1f}% of a leg's length" in capsys.readouterr().out
    lift = {posture: max(abs(change["foot_lift"]) for change in data["posture"].values()) for posture, data in reports.items()}
    assert lift["keep"] < 0.002 < lift["free"]


@pytest.mark.heavy
def test_cli_unconverged_run_fails_without_writing_the_mesh(mesh_files, tmp_path, registry, capsys):
    from allorules.cli import main

    mesh, labels = mesh_files
    ruleset = _contradictory_ruleset(tmp_path, registry)
    out, report = tmp_path / "out.obj", tmp_path / "report.json"
    status = main(["scale", str(mesh), "--ruleset", str(ruleset), "--mass-ratio", "1.1", "--segmentation", str(labels),
                   "--modes", str(MODES), "--no-cache", "-o", str(out), "--report", str(report)])
    assert status != 0
    captured = capsys.readouterr()
    assert "did not reach its targets" in captured.err and "no mesh written" in captured.err
    assert "foreleg-length-again" in captured.out            # the table is shown all the same
    assert not out.exists() and not (tmp_path / "out.unconverged.obj").exists()
    data = json.loads(report.read_text())
    assert data["converged"] is False and data["output"] is None
    assert {rule["id"] for rule in data["rules"]} >= {"foreleg-length", "foreleg-length-again"}


def test_cli_refuses_bad_requests(mesh_files, tmp_path):
    from allorules.cli import scale
    from allorules.errors import AllorulesError

    mesh, labels = mesh_files
    cases = [
        ([str(mesh), "--ruleset", "quadruped", "-o", str(tmp_path / "a.obj")], "needs --mass-ratio"),
        ([str(mesh), "--ruleset", "quadruped", "--mass-ratio", "0", "-o", str(tmp_path / "a.obj")], "mass ratio"),
        ([str(mesh), "--region", "head", "-o", str(tmp_path / "a.obj")], "needs --alpha"),
        ([str(mesh), "--ruleset", "quadruped", "--mass-ratio", "2", "-o", str(mesh)], "input mesh .* never overwritten"),
        ([str(mesh), "--ruleset", "quadruped", "--mass-ratio", "2"], "-o OUT"),
    ]
    for argv, message in cases:
        with pytest.raises(AllorulesError, match=message):
            scale.run(_parser().parse_args(["scale"] + argv))


def test_local_scaling_of_a_turned_mesh_is_the_same_edit_turned(animal, basis):
    """Meshes arrive in any orientation: both forms give the same animal, turned. The per-axis form
    works in the animal's own axes (from the labeller's frame, or from the regions when labels come
    from a file); in the mesh's axes a 30° turn changed its result by 3 % of the diagonal."""
    from scipy.spatial.transform import Rotation

    from allorules.body import Frame
    from allorules.solve.transform import anatomical_axes

    body = animal.body()
    rotation = Rotation.from_euler("xyz", [40, 25, -70], degrees=True).as_matrix()
    turned_frame = Frame(up=rotation @ body.frame.up, forward=rotation @ body.frame.forward)
    turned = Body(body.vertices @ rotation.T, body.faces, body.labels, body.region_names, turned_frame)
    from_labels = Body(turned.vertices, body.faces, body.labels, body.region_names)          # no frame
    turned_basis = basis.__class__(basis.eigenvalues, basis.vectors, basis.mass)   # rotation leaves L and D alone
    diagonal = np.linalg.norm(np.ptp(body.vertices, axis=0))
    np.testing.assert_allclose(anatomical_axes(turned), anatomical_axes(body) @ rotation.T, atol=1e-12)
    np.testing.assert_allclose(anatomical_axes(from_labels) @ rotation, anatomical_axes(Body(
        body.vertices, body.faces, body.labels, body.region_names)), atol=1e-12)
    assert abs(anatomical_axes(from_labels)[1] @ turned_frame.up) > 0.9     # the regions' up is nearly the frame's
    unframed = Body(body.vertices, body.faces, body.labels, body.region_names)
    for form in ("per-mode", "per-axis"):
        for original, turned_version in ((body, turned), (unframed, from_labels)):
            edited = scale_region(original, "forelimbs", 0.5, basis=basis, form=form).vertices
            again = scale_region(turned_version, "forelimbs", 0.5, basis=turned_basis, form=form).vertices @ rotation
            assert np.linalg.norm(again - edited, axis=1).max() / diagonal < 1e-9, form


@pytest.mark.slow
def test_misses_of_earlier_steps_are_carried_forward_not_added_up(animal, registry, monkeypatch):
    """Each step's output is enlarged by 0.4 % after the solve (as when fresh and carried measures
    of an output disagree). Seven such misses would put the mass 8.7 % over; carried forward,
    only the last step's 1.2 % is left (and the stress constraint, compared with the input, is
    met the same way); and that one the last step's refits take up."""
    import allorules.runs.ruleset_run as biology_scaling

    restore = biology_scaling.restore_limb_axes

    def restore_and_miss(reference, moved):
        vertices = restore(reference, moved)
        centre = vertices.mean(axis=0)
        return centre + 1.004 * (vertices - centre)

    monkeypatch.setattr(biology_scaling, "restore_limb_axes", restore_and_miss)
    ruleset = load_ruleset("isometric", registry)
    with monkeypatch.context() as without:
        without.setattr(biology_scaling, "LAST_STEP_REFITS", 0)
        result = _run(animal, registry, ruleset, 0.5)
    assert len(result.steps) == 7
    assert result.mass_ratio == pytest.approx(0.5 * 1.004 ** 3, rel=2e-3)     # the last step's miss only
    for step in result.steps[1:]:
        # each later step aims r / 1.012 below where it starts, so with its own miss it makes r
        assert step.mass_ratio == pytest.approx(step.target_mass_ratio, rel=2e-3)
    assert _run(animal, registry, ruleset, 0.5).mass_ratio == pytest.approx(0.5, rel=2e-3)


@pytest.mark.slow
@pytest.mark.shared_meshes
def test_low_poly_dog_scales_standing(shared_meshes, registry):
    """The shared low-poly game dog (485 vertices after its seams are merged, labelled
    automatically): before its heart girth was cut from the whole torso it could not be measured
    at all; upright only, its hind feet ended 25 % of a leg up at R = 2."""
    from allorules.mesh.repair import prepare_mesh
    from allorules.segment.labeller import label_quadruped

    prepared = prepare_mesh(shared_meshes / "dog-lowpoly.obj")
    body = label_quadruped(Body(prepared.vertices, prepared.faces))
    result = scale_with_ruleset(body, load_ruleset("quadruped", registry), 2.0, registry=registry, use_cache=False)
    assert result.converged, result.messages
    assert max(abs(change["foot_lift"]) for change in result.posture.values()) < 0.05


@pytest.mark.heavy
@pytest.mark.shared_meshes
def test_the_cows_hooves_grow_with_its_thickened_legs(shared_meshes, tmp_path):
    """The Princeton cow 381 at ×2 with the limbs' thickness (κ): with the foot kept at Eq. 9's size
    its hooves came out ×0.83–0.92 (smaller than the input's, on an animal twice as heavy) under
    legs swollen unevenly along them (girth spread 0.65–0.75). Each foot now grows with its leg as
    a whole: larger than isometric, its shape kept, the legs thickened evenly down to it. (Its
    default run needed κ until the blend zones blended their openings' mismatch, 7 December 2026;
    it now converges without, so κ is given by a ruleset, as a user gives it.)"""
    from allorules.cli import main

    ruleset = tmp_path / "thick.yaml"
    ruleset.write_text("extends: quadruped\nsolver:\n  limb_thickness: \"on\"\n")
    out, report = tmp_path / "cow-x2.obj", tmp_path / "cow-x2.json"
    assert main(["scale", str(shared_meshes / "psb-fourleg" / "381.off"), "--ruleset", str(ruleset),
                 "--mass-ratio", "2", "-o", str(out), "--report", str(report)]) == 0
    data = json.loads(report.read_text())
    assert data["converged"] and any(step["limb_thickness"] for step in data["step_details"])
    hooves = [feature for feature in data["quality"]["small_features"]
              if feature["kind"] == "end" and feature["region"] in ("forelimbs", "hindlimbs")]
    assert len(hooves) == 4
    for hoof in hooves:
        assert hoof["scale"] > 2 ** (1 / 3) and hoof["shape_change"] < 0.15, hoof
    assert max(leg["girth_spread"] for leg in data["quality"]["legs"]) < 0.45


@pytest.mark.slow
def test_a_run_whose_trunk_humps_beyond_the_limit_misses(animal, registry, monkeypatch):
    """A run that met every rule is not converged where its trunk changed shape beyond
    TRUNK_SHAPE_LIMIT (Spot at ×0.5 met every rule as a short, tall sack): the miss is a distortion,
    named in the run's messages, and the rules' budget is there to settle it."""
    from allorules.runs import ruleset_run

    ruleset = load_ruleset("quadruped", registry)
    met = _run(animal, registry, ruleset, 2.0)
    assert met.converged and met.trunk_shape < 0.4
    monkeypatch.setattr(ruleset_run, "trunk_shape_change", lambda before, after: 0.45)
    humped = _run(animal, registry, ruleset, 2.0)
    assert not humped.converged and humped.missed == ("distorted",)
    assert any("the trunk changed shape by 45%" in message and "limit 40%" in message for message in humped.messages)
    assert all(abs(rule.error) <= EXPONENT_TOLERANCE for rule in humped.rules)
    # humped as its length strayed, the shape is the trunk's miss, which holding its length mends:
    # such a run is made again with the hold first, as for the length alone (the donkey 385 at ×0.5)
    monkeypatch.setattr(ruleset_run, "TRUNK_LENGTH_TOLERANCE", abs(met.trunk_length_exponent - 1 / 3) / 2)
    shortened = _run(animal, registry, ruleset, 2.0)
    assert shortened.missed == ("trunk", "trunk-shape") and trunk_only(shortened.missed)
    assert shortened.settle_trunk() is None       # not its length alone: no rule on it settles it


def test_a_run_that_missed_only_its_trunk_is_held_first():
    """The tries after a miss (runs/pipeline._more_variables): the trunk's length held alone first
    where the trunk is the one miss, its shape with it or not; the limbs' thickness first otherwise
    (a distorted leg, a rule)."""
    from allorules.rules.model import SolverSettings
    from allorules.runs.pipeline import _more_variables

    solver = SolverSettings()
    for missed in (("trunk",), ("trunk", "trunk-shape")):
        assert trunk_only(missed)
        first = _more_variables(solver, missed)[0]
        assert first[0] == "trunk_hold" and first[2] == {"limb_thickness": "off", "trunk_hold": "on"}
    for missed in (("trunk", "distorted"), ("rule", "trunk"), ("distorted",), ("trunk-shape",)):
        assert not trunk_only(missed)
        assert _more_variables(solver, missed)[0][0] == "limb_thickness"
