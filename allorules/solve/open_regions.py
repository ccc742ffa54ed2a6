"""Regions no rule measures keep their proportions (METHOD §10: "nothing changes that nobody asked
to change").

Eq. 9 gives every region of the ruleset an α_j. A region that no rule measures is free, and the
solver lets it absorb whatever the others need: in the demo's ×2 horse the neck, which
``quadruped`` leaves open, grew from 0.288 to 0.330 of the body's length. The paper gives the neck
"1/3 as the baseline value predicted by isometric scaling"; this module makes that the default for
every open region and appendage (neck, tail, ears, horns, trunk):

* :func:`open_regions` — the regions of the ruleset and of the body that no rule measures, with
  their setting (``isometric`` or ``free``, :class:`allorules.rules.OpenRegions`);
* :func:`shape_held_regions` — those held by their shape (``hold: shape``, the default): each
  keeps its input shape scaled isometrically after Eq. 9 (:mod:`allorules.solve.held_regions`),
  so no energy term trades it against the rules;
* :func:`open_region_terms` — with ``hold: soft`` (or for a part the shape cannot hold), one soft
  energy term per isometric open region and held measure:
  ``weight · (q(x') / (q_0 · r^e_iso) − 1)²``, e_iso the measure's isometric exponent (length 1/3,
  mass 1). A rule of the ruleset on the region replaces it (the region is then not open);
* :func:`extra_regions` — appendages the body has but the ruleset does not list: each gets its
  own α in Eq. 9 when it is held isometric, so that it can be held;
* :func:`open_region_outcomes` — what each open region achieved over the run (its length and
  mass exponents), for the report.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass

from allorules.body import Body
from allorules.errors import AllorulesError

log = logging.getLogger("allorules")

REPORTED_MEASURES = ("length", "mass")   # reported for every open region, held or not

__all__ = ["OpenRegionOutcome", "open_regions", "shape_held_regions", "extra_regions", "open_region_terms",
           "open_region_outcomes"]


def _present(body: Body, region: str) -> bool:
    return body.labels is not None and body.has_region(region) and bool(body.region_mask(region).any())


def open_regions(ruleset, body: Body) -> dict[str, str]:
    """Every region of the ruleset that no rule of the ruleset measures, and every appendage of the
    body (a region the ruleset does not list: a tail, ears), with its setting (``isometric`` /
    ``free``), in the ruleset's order, then the body's.

    With ``hold: soft`` an appendage is open only when ``open_regions.regions`` names it: a soft-held
    one needs an α of its own in Eq. 9, and giving one to the generated animal's tail by default made
    a one-step run on it miss its chest girth (0.392 for 0.365). Held by its shape it needs none."""
    measured = {rule.region for rule in ruleset.rules if rule.region}
    named = ruleset.open_regions.regions
    shape = ruleset.open_regions.hold == "shape"
    names = list(ruleset.regions) + [name for name in body.region_names
                                     if name not in ruleset.regions and (shape or name in named)]
    return {name: ruleset.open_regions.setting(name) for name in names
            if name not in measured and _present(body, name)}


def shape_held_regions(ruleset, body: Body) -> tuple[str, ...]:
    """The isometric open regions held by their shape (``hold: shape``, the default)."""
    if ruleset.open_regions.hold != "shape":
        return ()
    return tuple(name for name, setting in open_regions(ruleset, body).items() if setting == "isometric")


def extra_regions(ruleset, body: Body, held: tuple[str, ...] = ()) -> tuple[str, ...]:
    """Regions the body has, the ruleset does not list, and the ruleset holds isometric by soft
    terms (not in ``held``, the regions held by their shape): each gets an α_j of its own in Eq. 9."""
    return tuple(name for name, setting in open_regions(ruleset, body).items()
                 if setting == "isometric" and name not in ruleset.regions and name not in held)


def open_region_terms(ruleset, body: Body, registry, measure, held: tuple[str, ...] = ()) -> tuple[list, list[str]]:
    """The soft isometric terms (:class:`allorules.solve.energy.Term`, kind ``"open-region"``) for
    ``body``'s isometric open regions other than ``held`` (those held by their shape), and a note
    for each term left out because its measure cannot be taken on this body (a default term nobody
    asked for never fails a run)."""
    from allorules.solve.energy import Term

    settings = ruleset.open_regions
    specs = registry.measures()
    terms, notes = [], []
    for region, setting in open_regions(ruleset, body).items():
        if setting != "isometric" or settings.weight <= 0 or region in held:
            continue
        for name in settings.measures:
            spec = specs.get(name)
            if spec is None:
                continue
            try:
                measure(name, body, region)
            except (AllorulesError, ValueError) as error:
                notes.append(f"open region {region}: its {name} cannot be measured ({error}); it is left free")
                continue
            terms.append(Term(f"open:{region}:{name}", "open-region", name, region, float(spec.isometric_exponent),
                              float(settings.weight)))
    for note in notes:
        log.warning("%s", note)
    return terms, notes


@dataclass(frozen=True)
class OpenRegionOutcome:
    """An open region over the whole run: one measure's achieved exponent e' = log(q_f/q_0)/log R
    against its isometric exponent, and whether the ruleset held it (``held``; ``hold``: by its
    ``shape`` or by ``soft`` terms) and it stayed within the tolerance (``met``; always True for a
    measure not held)."""

    region: str
    setting: str
    measure: str
    isometric_exponent: float
    achieved_exponent: float | None
    held: bool
    tolerance: float
    hold: str | None = None

    @property
    def met(self) -> bool:
        if not self.held:
            return True
        return self.achieved_exponent is not None and abs(self.achieved_exponent - self.isometric_exponent) <= self.tolerance

    def summary(self) -> str:
        """One phrase: what the measure's exponent reached against isometric."""
        achieved = "not measured" if self.achieved_exponent is None else f"{self.achieved_exponent:.3f}"
        return (f"open region {self.region}: {self.measure} exponent {achieved}, isometric "
                f"{self.isometric_exponent:.3f} (±{self.tolerance})")

    def as_dict(self) -> dict:
        return {"region": self.region, "setting": self.setting, "measure": self.measure, "held": self.held,
                "hold": self.hold,
                "isometric_exponent": float(self.isometric_exponent),
                "achieved_exponent": None if self.achieved_exponent is None else float(self.achieved_exponent),
                "tolerance": float(self.tolerance), "met": bool(self.met)}


def open_region_outcomes(ruleset, registry, initial: Body, final: Body, ratio: float, measure, held_ids: set[str],
                         tolerance: float, shape_held: tuple[str, ...] = ()) -> list[OpenRegionOutcome]:
    """Length and mass exponents of every open region over a run (fresh measures of input and
    output), and of any other measure the ruleset holds them at. ``held_ids``: the soft terms' ids;
    ``shape_held``: the regions held by their shape (every measure of theirs is held)."""
    specs = registry.measures()
    outcomes = []
    names = tuple(dict.fromkeys(REPORTED_MEASURES + tuple(ruleset.open_regions.measures)))
    for region, setting in open_regions(ruleset, initial).items():
        for name in names:
            spec = specs.get(name)
            if spec is None:
                continue
            achieved = None
            try:
                before, after = measure(name, initial, region), measure(name, final, region)
                achieved = math.log(after / before) / math.log(ratio) if ratio != 1.0 else float(spec.isometric_exponent)
            except (AllorulesError, ValueError) as error:
                log.debug("open region %s: %s not measured: %s", region, name, error)
            soft = f"open:{region}:{name}" in held_ids
            hold = "shape" if region in shape_held else ("soft" if soft else None)
            outcomes.append(OpenRegionOutcome(region, setting, name, float(spec.isometric_exponent), achieved,
                                              hold is not None, tolerance, hold))
    return outcomes
