"""What the add-on shows after a run: a short table from a run's report (no ``bpy`` here).

:func:`run_summary` turns the report of :func:`allorules.blender.adapter.scale_arrays` into the
few figures the sidebar panel draws and the object keeps: each rule's target and achieved
exponent and whether it was met (within the report's exponent tolerance), the mass and stress
ratios, and the warnings.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any


@dataclass(frozen=True)
class RuleRow:
    """One rule of a run: the exponent asked for, the exponent measured, met or not."""

    id: str
    target: float
    achieved: float
    met: bool


@dataclass(frozen=True)
class RunSummary:
    """A run as the panel shows it."""

    object: str                      # the new object's name
    source: str                      # the original's name
    kind: str                        # "ruleset" or "global"
    ruleset: str
    target_mass_ratio: float
    mass_ratio: float
    stress_ratio: float | None
    rules: tuple[RuleRow, ...] = ()
    warnings: tuple[str, ...] = ()
    repairs: tuple[str, ...] = ()
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def all_met(self) -> bool:
        return all(rule.met for rule in self.rules)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "RunSummary":
        data = dict(data)
        data["rules"] = tuple(RuleRow(**rule) for rule in data.get("rules", ()))
        data["warnings"] = tuple(data.get("warnings", ()))
        data["repairs"] = tuple(data.get("repairs", ()))
        return cls(**data)

    def line(self) -> str:
        """One line for the status bar / an INFO report."""
        stress = "" if self.stress_ratio is None else f", stress ×{self.stress_ratio:.3f}"
        rules = f", {sum(r.met for r in self.rules)}/{len(self.rules)} rules met" if self.rules else ""
        warned = f", {len(self.warnings)} warning(s): see the allorules panel" if self.warnings else ""
        return f"{self.object}: mass ×{self.mass_ratio:.3f} (target {self.target_mass_ratio:g}){stress}{rules}{warned}"


def run_summary(report: dict[str, Any], *, object_name: str, source_name: str) -> RunSummary:
    """The panel's summary of a run's report (as :func:`scale_arrays` returns it)."""
    tolerance = float(report.get("tolerances", {}).get("exponent", 0.02))
    rules = tuple(RuleRow(rule["id"], float(rule["exponent"]), float(rule["achieved_exponent"]),
                          abs(float(rule["achieved_exponent"]) - float(rule["exponent"])) <= tolerance + 1e-12)
                  for rule in report.get("rules", ()))
    stress = report.get("stress_ratio")
    quality = report.get("quality") or {}
    unfolded = int(quality.get("unfolded_faces") or 0)
    # the run's own warning about folded faces is about the mesh solved; the object added had them smoothed back
    smoothed = (f"{unfolded} folded face(s) were smoothed back before the object was added (the farthest vertex "
                f"moved {100 * float(quality.get('unfold_largest_move') or 0):.1f}% of the body's size)",) if unfolded else ()
    return RunSummary(
        object=object_name, source=source_name, kind=str(report.get("mode", "")), ruleset=str(report.get("ruleset", "")),
        target_mass_ratio=float(report["target_mass_ratio"]), mass_ratio=float(report["mass_ratio"]),
        stress_ratio=None if stress is None else float(stress), rules=rules,
        warnings=tuple(report.get("warnings", ())) + tuple(report.get("messages", ())) + smoothed,
        repairs=tuple(report.get("repairs", ())),
    )
