"""The run pipeline: prepare → label → scale → place → save, with the report. Every front end calls it:
``allorules scale``, ``measure`` and ``segment``, batch runs, the demo, the Python API
(:mod:`allorules.api`) and the Blender add-on.

1. :func:`prepare`: the user's file (or a ``trimesh.Trimesh``, or a :class:`~allorules.body.Body`)
   becomes a repaired body that remembers how it maps back onto the input (METHOD §1); a body
   above the working size gets a working mesh (:func:`working`, METHOD §9), on which everything
   else happens and from which the result is carried back to every vertex of the user's body.
2. :func:`label`: regions from a labels file (allorules JSON or Princeton ``.seg``), given per
   input vertex (:class:`VertexRegions`: the Blender add-on's vertex groups, which
   :func:`input_regions` makes) or from a segmenter through the plugin hook (the ruleset's,
   ``auto-quadruped`` by default); then regions nobody asked for are folded into their neighbour
   (:func:`allorules.segment.regions.fold_regions`).
   The body's :class:`~allorules.body.Labelling` says which file or segmenter labelled it.
3. :func:`scale`: one of the four kinds of scaling (:data:`Scaling`).
4. :func:`place`: the output stands where the input stood: its feet on the input's ground plane at
   the same place (METHOD §10; ``placement="centroid"`` keeps the centroid in place instead).
5. :func:`save_output` / :func:`save_picture`: the output in the input's own vertex layout (UVs,
   materials and detached parts kept) and a before/after picture; :meth:`Run.report` is the JSON,
   with the quality measures an artist would look for (:mod:`allorules.measure.quality`).

:func:`run` does 1-4 and returns a :class:`Run`.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Iterable, Union

import numpy as np

from allorules import __version__
from allorules.body import Body, Frame, Labelling
from allorules.errors import (
    AllorulesError,
    MeasurementError,
    OutputError,
    ScalingError,
    SegmentationError,
)
from allorules.files import same_file
from allorules.measure.frame import regions_frame
from allorules.measure.girth import heart_girth_tape
from allorules.measure.ground import GroundError, ground_contact, place_on_ground
from allorules.measure.mass import body_mass
from allorules.measure.quality import (
    TRUNK_SHAPE_WARNING,
    QualityReport,
    flipped_faces,
    quality_report,
)
from allorules.measure.stress import SectionChoice, peak_stress
from allorules.mesh.geometry import count_flipped_faces, vertex_areas
from allorules.mesh.repair import PreparedMesh, prepare_mesh
from allorules.mesh.transfer import Binding, bind, carry_deformation, carry_labels
from allorules.mesh.unfold import Unfolding, unfold_faces
from allorules.mesh.working import (
    WorkingMesh,
    WorkingRecord,
    check_working_vertices,
    make_working_mesh,
    split_working_mesh,
)
from allorules.output.export import SaveResult, save_mesh
from allorules.plugins.registry import PluginRegistry, registry_for
from allorules.rules.model import Ruleset, SegmenterUse
from allorules.runs.global_run import scale_globally, scale_globally_raw
from allorules.runs.local import scale_region, seam_strain
from allorules.runs.progress import RunProgress
from allorules.runs.results import (
    EXPONENT_TOLERANCE,
    TRUNK_LENGTH_RETRY,
    TRUNK_LENGTH_TOLERANCE,
    BiologyScalingResult,
    LocalResult,
    RawGlobalResult,
    ScalingResult,
    trunk_longer,
    trunk_only,
)
from allorules.runs.ruleset_run import (
    BASIS_EVERY,
    scale_with_ruleset,
)
from allorules.segment.labels_io import (
    LabelsFile,
    UnsaidMeshError,
    labels_file_beside,
    read_labels,
    read_labels_file,
    read_seg,
    write_labels,
)
from allorules.segment.regions import NEIGHBOUR_REGION, QUADRUPED_REGIONS, fold_regions

log = logging.getLogger("allorules")


# ---------------------------------------------------------------------------------------------
# What to do


@dataclass(frozen=True)
class GlobalScaling:
    """Paper §3.1: one α for the whole body; the mass changes by ``mass_ratio`` at unchanged peak
    limb stress (``section`` overrides where the stress is taken)."""

    mass_ratio: float
    section: SectionChoice | None = None


@dataclass(frozen=True)
class RulesetScaling:
    """Paper §3.3: the ruleset's rules and constraints met at body-mass ratio ``mass_ratio``."""

    ruleset: Ruleset
    mass_ratio: float
    section: SectionChoice | None = None


@dataclass(frozen=True)
class RawGlobalScaling:
    """Paper Eq. 4 once, with the user's α and isometric factor s (no measuring)."""

    alpha: float
    scale: float = 1.0


@dataclass(frozen=True)
class LocalScaling:
    """Paper Eq. 5-7 on one region; ``arithmetic_factor`` instead scales the region's vertices (the
    paper's bad example, for comparison only)."""

    region: str
    alpha: float = 0.0
    arithmetic_factor: float | None = None
    form: str = "per-axis"


Scaling = Union[GlobalScaling, RulesetScaling, RawGlobalScaling, LocalScaling]


@dataclass(frozen=True)
class VertexRegions:
    """Regions given for every vertex of the input as it came, not through a file (a Blender mesh's
    vertex groups): ``labels[k]`` indexes ``region_names`` for input vertex ``k``, -1 for none;
    ``source`` says where they came from (the report's labelling); ``frame``, the body's up and
    forward as whoever labelled it found them (the measures' axes; ``None``: from the regions)."""

    labels: np.ndarray
    region_names: tuple[str, ...]
    source: str
    frame: Frame | None = None

    def on(self, prepared: PreparedMesh) -> Body:
        """The prepared body with these regions (input vertices mapped onto the body's)."""
        labels = np.asarray(self.labels, dtype=np.int64)
        if labels.shape != (prepared.source_vertex_count,):
            raise SegmentationError(f"{self.source}: {len(labels)} labels for a mesh of "
                                    f"{prepared.source_vertex_count} vertices; they must come from this mesh")
        if labels.size and (labels.min() < -1 or labels.max() >= len(self.region_names)):
            raise SegmentationError(f"{self.source}: a label is not a region index (0 … {len(self.region_names) - 1}, "
                                    "or -1 for none)")
        return Body(prepared.vertices, prepared.faces).with_labels(prepared.body_labels(labels), self.region_names,
                                                                  Labelling(self.source), self.frame)


PLACEMENTS = ("ground", "centroid")
Result = Union[ScalingResult, RawGlobalResult, LocalResult]


# ---------------------------------------------------------------------------------------------
# The stages


def prepare(source: str | Path | Any) -> PreparedMesh:
    """A mesh file, a ``trimesh.Trimesh`` or a :class:`Body` as a prepared body (each repair logged).

    A ``Body`` is taken as already prepared (the generated quadruped, a body from the API); its
    labels, if any, travel with it (see :func:`run`)."""
    if isinstance(source, Body):
        return PreparedMesh(source.vertices, source.faces, [])
    prepared = prepare_mesh(source)
    for repair in prepared.repairs:
        log.info("prepare: %s", repair)
    return prepared


@dataclass(frozen=True)
class Working:
    """The mesh a run works on (:class:`~allorules.mesh.working.WorkingMesh`) and where each vertex
    of the user's body sits on it (``binding``; ``None`` when the body is used as it is)."""

    mesh: WorkingMesh
    binding: Binding | None
    also_tried: tuple[WorkingTry, ...] = ()   # other working meshes the run missed on (_coarser_working)

    def body(self) -> Body:
        return Body(self.mesh.vertices, self.mesh.faces)

    def from_user(self, user: Body) -> Body:
        """The working body with the regions of a labelled user body (labels carried across)."""
        if self.binding is None:
            return user
        to_user = bind(self.mesh.vertices, user.vertices, user.faces)
        labels = carry_labels(to_user, user.labels)
        return Body(self.mesh.vertices, self.mesh.faces, labels, user.region_names, user.frame, user.labelling,
                    tape=user.tape)

    def labels_to_user(self, body: Body, user: Body) -> Body:
        """The user's body with the working body's regions (each user vertex takes its working
        triangle's); unlabelled where the working body is (a raw Eq. 4 run)."""
        if self.binding is None:
            return body
        if body.labels is None:
            return user
        return user.with_labels(carry_labels(self.binding, body.labels), body.region_names, body.labelling, body.frame)

    def to_user(self, working_before: np.ndarray, working_after: np.ndarray, user_before: np.ndarray) -> np.ndarray:
        """The user's vertices after the working mesh moved (its detail moves and turns with it)."""
        if self.binding is None:
            return np.asarray(working_after, dtype=float)
        return carry_deformation(self.binding, working_before, working_after, user_before)

    def report(self) -> dict[str, Any]:
        mesh = self.mesh
        return {"method": mesh.method, "vertices": int(len(mesh.vertices)), "target_vertices": int(mesh.target_vertices),
                "user_vertices": int(mesh.source_vertices), "seconds": round(float(mesh.seconds), 3),
                "quality": {key: round(float(value), 4) for key, value in mesh.quality.items()},
                "also_tried": [{"vertices": other.vertices, "missed": other.missed} for other in self.also_tried]}


@dataclass(frozen=True)
class WorkingTry:
    """A working mesh a run missed its targets on (it was made again on a coarser one)."""

    vertices: int
    missed: str       # the run's first message there


COARSER_WORKING = (4000, 2500)   # tried in turn where the default working mesh misses


def working(prepared: PreparedMesh, vertices: int | None = None, record: WorkingRecord | None = None) -> Working:
    """The working mesh of a prepared body: the body itself at or below ``vertices`` (default
    :data:`allorules.mesh.working.WORKING_VERTICES`), else a remesh of that size, bound to it. A
    ``record`` (a run's output's labels file's) gives the working mesh at its recorded points of the
    body instead, unless another size is asked or the points no longer make a mesh."""
    mesh = None
    if record is not None and (vertices is None or int(vertices) == record.target_vertices):
        mesh = record.on(prepared.vertices, prepared.faces)
        if mesh is not None:
            log.info("%s", mesh.describe())
    if mesh is None:
        mesh = make_working_mesh(prepared.vertices, prepared.faces, vertices,
                                 name=str(prepared.source_path) if prepared.source_path else "mesh")
    binding = None if mesh.is_source else bind(prepared.vertices, mesh.vertices, mesh.faces)
    return Working(mesh, binding)


def labelled_working(prepared: PreparedMesh, *, registry: PluginRegistry, working_vertices: int | None = None,
                     segmenter: SegmenterUse | None = None, labels: str | Path | VertexRegions | None = None,
                     given: Body | None = None, up: np.ndarray | None = None, forward: np.ndarray | None = None,
                     regions: Iterable[str] = QUADRUPED_REGIONS, labels_beside: bool = True) -> tuple[Working, Body]:
    """The working mesh and the working body with regions, as a run and ``allorules measure`` get
    them (:func:`working`, :func:`label_working`): with no ``labels`` or ``given`` body, a mesh
    file's own labels file beside it (``labels_beside``) gives its regions and, where it recorded
    the working mesh its run measured on (a run's output's), that working mesh at the same points."""
    beside = read_labels_beside(prepared) if labels is None and given is None and labels_beside else None
    work = working(prepared, working_vertices, beside.working if beside is not None else None)
    body = label_working(prepared, work, registry=registry, segmenter=segmenter, labels=labels, given=given, up=up,
                         forward=forward, regions=regions, beside=beside)
    return work, body


def label_working(prepared: PreparedMesh, work: Working, *, registry: PluginRegistry,
                  segmenter: SegmenterUse | None = None, labels: str | Path | VertexRegions | None = None,
                  given: Body | None = None, up: np.ndarray | None = None, forward: np.ndarray | None = None,
                  regions: Iterable[str] = QUADRUPED_REGIONS, beside: LabelsFile | None = None) -> Body:
    """The working body with regions: from a labels file, regions given per input vertex or a
    ``given`` labelled body (all for the user's prepared body, carried across to the working mesh),
    else from the mesh file's own labels file beside it (``beside``, as :func:`read_labels_beside`
    read it: a run's output measured with the regions the run measured, :func:`save_output`), else
    from the segmenter on the working mesh itself; regions not among ``regions`` fold into their
    neighbour. On a working mesh made from the labels file's record its recorded regions are taken
    as they are (nothing carried). :func:`labelled_working` reads the file and makes the working
    mesh for it."""
    if labels is None and given is None and beside is not None:
        given = beside.body
        if up is not None or forward is not None:
            log.warning("--up/--forward are ignored: the regions and axes come from the labels file beside the mesh")
        record = beside.working
        if work.mesh.method == "recorded" and record is not None and record.labels is not None:
            return _framed(fold_regions(Body(work.mesh.vertices, work.mesh.faces, record.labels, given.region_names,
                                             given.frame, given.labelling, tape=given.tape), tuple(regions)), given=True)
    if labels is None and given is None:
        return _framed(label(work.body(), registry=registry, segmenter=segmenter, up=up, forward=forward,
                             regions=regions))
    if isinstance(labels, VertexRegions):
        user = labels.on(prepared)
    elif labels is None:
        user = given
    else:
        user = label(Body(prepared.vertices, prepared.faces), registry=registry, labels=labels, up=up,
                     forward=forward, regions=())
    return _framed(fold_regions(work.from_user(user), tuple(regions)), given=True)


STALE_FRAME_DEGREES = 45.0   # a given frame this far from its regions' own is another orientation's


def _framed(body: Body, given: bool = False) -> Body:
    """``body`` with a frame: its own (the labeller's, a labels file's), else read off its regions
    (:func:`allorules.measure.frame.regions_frame`), so that every measure, the per-axis power law
    and the ground use one up and one forward. A ``given`` frame (a labels file's, a body's) that
    is ``STALE_FRAME_DEGREES`` or more from its regions' own was found on the mesh in another
    orientation (exported turned since it was labelled): the regions' own is used, with a warning.
    (The regions' own is within 2° of the labeller's standing, 10° walking, 34° sitting.)"""
    if body.labels is None or (body.frame is not None and not given):
        return body
    frame = regions_frame(body)
    if frame is None:
        return body
    if body.frame is not None:
        turned = max(_degrees(body.frame.up, frame.up), _degrees(body.frame.forward, frame.forward))
        if turned < STALE_FRAME_DEGREES:
            return body
        source = body.labelling.source if body.labelling else "the regions given"
        log.warning("%s: its up and forward are %.0f° from those of its regions on this mesh (was the mesh turned "
                    "since it was labelled?); the regions' own are used", source, turned)
    labelling = body.labelling or Labelling("given")
    labelling = replace(labelling, notes=tuple(labelling.notes) + ("up and forward read off the regions (the plane "
                                                                   "of the feet, abdomen to chest)",))
    return body.with_labels(body.labels, body.region_names, labelling, frame)


def _degrees(first: np.ndarray, second: np.ndarray) -> float:
    cosine = float(np.dot(first, second) / (np.linalg.norm(first) * np.linalg.norm(second)))
    return float(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))))


def input_regions(source: str | Path | Any, *, registry: PluginRegistry | None = None,
                  segmenter: SegmenterUse | None = None, up: np.ndarray | None = None,
                  forward: np.ndarray | None = None, working_vertices: int | None = None) -> tuple[VertexRegions, Body]:
    """Every region the segmenter finds, as a run finds them (on the working mesh), for every vertex
    of the input as it came (a detached part takes its anchor's region), and the working body
    labelled (its frame, its labelling's confidence). What the Blender add-on writes as vertex groups
    for the artist to check and paint, then gives back to :func:`run` (``labels``)."""
    registry = registry if registry is not None else registry_for(None)
    check_working_vertices(working_vertices)
    prepared = prepare(source)
    work = working(prepared, working_vertices)
    on_working = label(work.body(), registry=registry, segmenter=segmenter, up=up, forward=forward, regions=())
    user = work.labels_to_user(on_working, Body(prepared.vertices, prepared.faces))
    source_text = on_working.labelling.source if on_working.labelling else "segmenter"
    return VertexRegions(prepared.source_labels(user.labels), tuple(user.region_names), source_text,
                         on_working.frame), on_working


def wanted_regions(ruleset: Ruleset | None) -> tuple[str, ...]:
    """The regions a run keeps apart: the six of a quadruped, every region the ruleset names (in its
    regions, its rules or its open_regions) and, when open regions are held by their shape (the
    default), every appendage (tail, ears, horns, trunk, ...) the ruleset does not set free."""
    names = list(QUADRUPED_REGIONS)
    if ruleset is not None:
        names += [name for name in ruleset.regions if name not in names]
        names += [rule.region for rule in ruleset.rules if rule.region and rule.region not in names]
        # an appendage the ruleset's open_regions holds isometric (a named tail) is kept apart too
        opened = ruleset.open_regions
        names += [name for name, setting in opened.regions.items() if name not in names and setting == "isometric"]
        if opened.hold == "shape":
            # held by its shape an appendage costs the solver nothing, and folded into its neighbour it
            # takes the neighbour's exponent (the real horse's tail whipped out to twice its length at
            # ×0.5 once the neck was held): every appendage a segmenter finds is kept apart and held
            names += [name for name in NEIGHBOUR_REGION if name not in names and opened.setting(name) == "isometric"]
    return tuple(names)


def label(
    body: Body,
    *,
    registry: PluginRegistry,
    segmenter: SegmenterUse | None = None,
    labels: str | Path | None = None,
    up: np.ndarray | None = None,
    forward: np.ndarray | None = None,
    regions: Iterable[str] = QUADRUPED_REGIONS,
) -> Body:
    """``body`` with regions, from the ``labels`` file or the ``segmenter`` (default
    ``auto-quadruped``) called through the plugin registry; regions not among ``regions`` join
    their neighbour. ``up``/``forward`` go to a segmenter that takes them."""
    if labels is not None:
        labelled = _read_labels_file(Path(labels), body)
        if up is not None or forward is not None:
            log.warning("--up/--forward are ignored: the regions come from %s", labels)
    else:
        labelled = _segment(body, registry, segmenter or SegmenterUse(), up, forward)
    return fold_regions(labelled, tuple(regions))


def read_labels_beside(prepared: PreparedMesh) -> LabelsFile | None:
    """The prepared body's own ``NAME.labels.json`` beside its file, where there is one made for this
    mesh (same faces): its regions and any working mesh it recorded. One made for another mesh is
    passed over, saying so."""
    if prepared.source_path is None:
        return None
    path = labels_file_beside(prepared.source_path)
    if not path.is_file():
        return None
    try:
        found = read_labels_file(path, Body(prepared.vertices, prepared.faces), same_faces=True)
    except UnsaidMeshError as error:      # never read beside a mesh before: passed over, as then
        log.info("%s; not read beside the mesh (give it with --segmentation to use it)", error)
        return None
    except SegmentationError as error:
        log.warning("%s; labelling the mesh afresh (give a labels file with --segmentation to use one)", error)
        return None
    log.info("regions from %s, beside the mesh (--relabel labels it afresh)", path)
    return replace(found, body=_labelled_from(path, found.body))


def _read_labels_file(path: Path, body: Body) -> Body:
    if path.suffix.lower() == ".seg":
        return _labelled_from(path, read_seg(path, body, QUADRUPED_REGIONS))
    return _labelled_from(path, read_labels(path, body))


def _labelled_from(path: Path, labelled: Body) -> Body:
    """``labelled`` saying it came from the labels file ``path`` (and what its segmenter said)."""
    source = Labelling(f"labels file {path}")
    if labelled.labelling is not None:   # a labels file written by a segmenter keeps what it said
        source = Labelling(f"labels file {path} ({labelled.labelling.source})", labelled.labelling.confidence,
                           labelled.labelling.notes)
    return labelled.with_labels(labelled.labels, labelled.region_names, source)


def _segment(body: Body, registry: PluginRegistry, use: SegmenterUse, up, forward) -> Body:
    spec = registry.segmenter(use.name)
    options = spec.complete_parameters(use.options)
    for name, direction in (("up", up), ("forward", forward)):
        if direction is None:
            continue
        if name not in spec.parameter_specs():
            raise SegmentationError(f"segmenter {use.name!r} does not take --{name}; leave it out or use a "
                                    "segmenter that does (allorules plugins)")
        options[name] = np.asarray(direction, dtype=float)
    plugin = registry.provider("segmenter", use.name)
    labelled = spec.segment(Body(body.vertices, body.faces), **options)
    source = f"segmenter {use.name}" + ("" if plugin == "builtin" else f" (plugin {plugin})")
    said = labelled.labelling
    return labelled.with_labels(labelled.labels, labelled.region_names,
                                Labelling(source, dict(said.confidence) if said else {}, said.notes if said else ()))


def scale(body: Body, scaling: Scaling, *, registry: PluginRegistry, modes: int | None = None,
          use_cache: bool = True, progress: RunProgress | None = None) -> Result:
    """Scale a labelled ``body`` as ``scaling`` says. Raises :class:`~allorules.errors.ScalingError`
    (with ``closest``) when a step cannot be solved at all; an unconverged ruleset run returns its
    result with ``converged`` false and ``messages`` saying what was missed."""
    if isinstance(scaling, RulesetScaling):
        return _scale_with_ruleset(body, scaling, registry=registry, modes=modes, use_cache=use_cache, progress=progress)
    if isinstance(scaling, GlobalScaling):
        return scale_globally(body, scaling.mass_ratio, modes=modes, section=scaling.section, use_cache=use_cache,
                              progress=progress)
    if isinstance(scaling, RawGlobalScaling):
        scaled = scale_globally_raw(body, scaling.alpha, scaling.scale, modes, use_cache=use_cache)
        return RawGlobalResult(scaled, scaling.alpha, scaling.scale, body_mass(scaled) / body_mass(body),
                               count_flipped_faces(body.vertices, scaled.vertices, body.faces))
    if isinstance(scaling, LocalScaling):
        if scaling.region not in body.region_names:
            raise SegmentationError(f"no region {scaling.region!r}; the body has {', '.join(body.region_names)}")
        scaled = scale_region(body, scaling.region, scaling.alpha, modes=modes, arithmetic_factor=scaling.arithmetic_factor,
                              use_cache=use_cache, form=scaling.form)
        seam = seam_strain(body.vertices, scaled.vertices, body.faces, body.region_mask(scaling.region))
        return LocalResult(scaled, scaling.region, scaling.alpha, scaling.arithmetic_factor, scaling.form, seam,
                           count_flipped_faces(body.vertices, scaled.vertices, body.faces))
    raise TypeError(f"not a kind of scaling: {scaling!r}")


def _scale_with_ruleset(body: Body, scaling: RulesetScaling, *, registry: PluginRegistry, modes: int | None,
                        use_cache: bool, progress: RunProgress | None) -> BiologyScalingResult:
    """A ruleset run and its further tries (:func:`_ruleset_tries`), each step's basis serving up to
    ``BASIS_EVERY`` steps (issue 16 §4); where every try misses, all of them made again with each
    step on a basis of its own mesh, as the paper makes every step, kept if that converges. A basis
    serving four steps is the speed's approximation, and where a run's path through its steps is on
    a knife's edge it decides it: the donkey 385 at ×2 missed its heart girth (0.386 for 0.365) and
    every try after, and with a basis every step (or one for all eight) it converges, its trunk
    held (0.363). Not where the trunk is the one miss (:func:`allorules.runs.results.trunk_only`)."""
    result = _ruleset_tries(body, scaling, registry=registry, modes=modes, use_cache=use_cache, progress=progress)
    if result.converged or BASIS_EVERY == 1 or trunk_only(result.missed):
        # a trunk that is the one miss is the ruleset's demand, not the path's (the galloping horse
        # at ×2 after 12 minutes of tries): said as it is, not made again
        return result
    log.warning("every try missed its targets (%s); making them again with each step on a basis of its own mesh "
                "(slower)", result.messages[0] if result.messages else "a target missed")
    try:
        again = _ruleset_tries(body, scaling, registry=registry, modes=modes, use_cache=use_cache, progress=progress,
                               basis_every=1)
    except (ScalingError, MeasurementError) as error:    # one more miss, not the end of the command
        again = _FailedTry(str(error))
    if not again.converged:
        result.warnings.append("made again with each step on a basis of its own mesh, the run did not converge "
                               f"either ({again.messages[0] if again.messages else 'a target missed'})")
        log.warning("%s", result.warnings[-1])
        return result
    again.warnings.insert(0, f"the run converged only with each step on a basis of its own mesh (a basis serving "
                             f"{BASIS_EVERY} steps, every try missed: {result.messages[0] if result.messages else ''})")
    log.warning("%s", again.warnings[0])
    return again


def _ruleset_tries(body: Body, scaling: RulesetScaling, *, registry: PluginRegistry, modes: int | None,
                   use_cache: bool, progress: RunProgress | None, basis_every: int | None = None
                   ) -> BiologyScalingResult:
    """A ruleset run (each basis serving ``basis_every`` steps, default ``BASIS_EVERY``), and what
    is tried when it misses with its open regions held by their shape
    (the default), in this order (a run kept in its first try or with κ alone whose trunk's length
    strayed beyond ``TRUNK_LENGTH_RETRY`` of isometric is also made again with the trunk held:
    :func:`_trunk_nearer_isometric`):

    1. with ``solver.limb_thickness: when-needed`` (the default), the run is made again with κ, the
       limbs' thickness, as one more variable (:mod:`allorules.solve.limb_thickness`), kept if it
       converges and kept on for the tries after it (the pig 383 and the donkey 385 at ×2); then,
       with the per-axis transform, with δ, the trunk's stretch along the body: first with the
       trunk's length held at its isometric exponent by a soft term, δ its lever
       (``solver.trunk_hold: when-needed``), then with δ free (``solver.trunk_stretch:
       when-needed``), each kept if it converges (which asks the trunk's length exponent to stay
       within ``TRUNK_LENGTH_TOLERANCE`` of isometric; a warning says what it reached). The rules
       can ask the chest for more mass than its heart girth allows (the real horse at ×2: mass
       exponent 1.14 with girth 0.365), which Eq. 9's one α per region cannot give without changing
       what no rule measures (docs/method.md, the trunk's length); held, the trunk grows no more
       than that needs, where δ free lands anywhere the check allows (or beyond: the bull 386 at
       ×2, 0.726). A run whose one miss is the trunk's length tries the hold alone, then κ and the
       hold together, then κ alone, then δ free (:func:`_more_variables`);
    2. then with ``hold: soft`` (the appendages folded as that setting folds them), kept only if it
       meets every target *and* keeps every open region within the exponent tolerance of
       isometric: a soft run that meets the rules by letting the neck or the tail go (the real
       horse at ×2: neck length exponent 0.515, the tail swung out level) changed what nobody
       asked to change, which is worse than an honest miss;
    3. else the first run is reported, not converged, with warnings saying what the others did."""
    def run(ruleset, labelled):
        return scale_with_ruleset(labelled, ruleset, scaling.mass_ratio, registry=registry, modes=modes,
                                  section=scaling.section, use_cache=use_cache, progress=progress,
                                  basis_every=basis_every)

    def again_with(ruleset, labelled) -> BiologyScalingResult | _FailedTry:
        # A run made again that stops is one more run that missed (the result it reached says which
        # step, or its error says why), not the end of the command: the cow 381 sitting at ×2, held
        # by soft terms, could not measure its folded horns' volume (at step 6, then, measured on a
        # new working mesh, at the start), and the first run and what the others did were lost with
        # a one-line error about horns nobody asked to scale.
        try:
            return run(ruleset, labelled)
        except ScalingError as error:
            if isinstance(error.closest, BiologyScalingResult):
                return error.closest
            return _FailedTry(str(error))
        except MeasurementError as error:
            return _FailedTry(str(error))

    def run_with(solver):
        return again_with(replace(scaling.ruleset, solver=solver), body)

    result = run(scaling.ruleset, body)
    opened, solver = scaling.ruleset.open_regions, scaling.ruleset.solver
    if result.converged:
        return _trunk_nearer_isometric(result, solver, run_with)
    if opened.hold != "shape" or not any(outcome.held and outcome.hold == "shape" for outcome in result.open_regions):
        return result
    missed = result.messages[0] if result.messages else "a target missed"
    settle = result.settle_trunk()
    if settle:      # said now: the tries below can take several times the first run (12 min on the galloping horse)
        log.warning("%s; first trying to keep it in proportion with more runs", settle)
    tried: list[str] = []          # what the runs not kept did, for the warnings of the one kept
    for variable, what, settings in _more_variables(solver, result.missed):
        solver = replace(solver, **settings)
        log.warning("the open regions held by their shape, the run missed its targets (%s); trying again with %s",
                    missed, what)
        again = run_with(solver)
        if again.converged:
            trunk = again.trunk_length_exponent if variable in ("trunk_stretch", "trunk_hold") else None
            grown = "" if trunk is None else f"length exponent {trunk:.3f}, isometric 0.333; "
            again.warnings.insert(0, f"the open regions held by their shape, the rules were met only with {what} "
                                     f"({grown}solver.{variable}); without it: {missed}")
            log.warning("%s", again.warnings[0])
            return _trunk_nearer_isometric(again, solver, run_with) if variable == "limb_thickness" else again
        why = again.messages[0] if again.messages else "a target missed"
        tried.append(f"with {what} the run did not help ({why})")
        log.warning("%s", tried[-1])
    log.warning("the open regions held by their shape, the run missed its targets (%s); trying again with them "
                "held by soft terms", missed)
    # every appendage the body has is named, so that the soft run holds it too (and is judged on it):
    # left to hold: soft's default it would fold into its neighbour and follow that region's rules
    # (the camel's tail, folded into the abdomen at ×2, vanished into the rump)
    appendages = {name: "isometric" for name in body.region_names
                  if name in NEIGHBOUR_REGION and opened.setting(name) == "isometric"}
    soft = replace(scaling.ruleset, open_regions=replace(opened, hold="soft", regions={**appendages, **opened.regions}))
    again = again_with(soft, fold_regions(body, wanted_regions(soft)))
    strayed = [outcome for outcome in again.open_regions if not outcome.met]
    if not again.converged or strayed:
        why = (again.messages[0] if again.messages else "a target missed") if not again.converged else (
            "it met the rules but " + "; ".join(outcome.summary() for outcome in strayed))
        tried.append(f"held by soft terms instead of by their shape, the open regions did not help ({why}); "
                     "the run held by shape is kept; to let them take up the difference anyway, give a "
                     "ruleset with open_regions: {hold: soft} (docs/rulesets.md)")
        log.warning("%s", tried[-1])
        result.warnings.extend(tried)
        return result
    again.warnings[:0] = [f"the open regions could not be held by their shape with every target met ({missed}); "
                          "they were held by soft terms instead (hold: soft), each within the tolerance of "
                          "isometric: see open_regions in the report", *tried]
    log.warning("%s", again.warnings[0])
    return again


@dataclass(frozen=True)
class _FailedTry:
    """A run made again that stopped with an error and no result of its own: the tries that
    follow read it as one more miss, its error the reason (:func:`_scale_with_ruleset`)."""

    reason: str
    converged: bool = False
    trunk_length_exponent: None = None
    open_regions: tuple = ()

    @property
    def messages(self) -> list[str]:
        return [self.reason]


def _trunk_nearer_isometric(result: BiologyScalingResult, solver, run_with) -> BiologyScalingResult:
    """``result``, a converged run, or the run made again with the trunk's length held isometric by
    a soft term (δ its lever, κ as ``solver`` has it) where the trunk strayed beyond
    ``TRUNK_LENGTH_RETRY`` of 1/3 (within ``TRUNK_LENGTH_TOLERANCE``, or the run would not have
    converged), kept if it converges with its trunk nearer 1/3 and its trunk not humped further from
    a stretch of the input's (:func:`_trunk_shape_worse`). Only where ``solver.trunk_hold`` is
    ``when-needed`` and the trunk could be held (δ allowed, per-axis transform); a trunk a rule
    measures is not checked (its exponent is None). Kept or not, the report says what the trunk
    reached: the real horse at ×2 met every rule with its trunk at 0.419 and its chest rising into
    its neck, where held (0.38) it is the same horse heavier. At ×0.5 it met them at 0.276, and held
    (0.335) its back sagged and its rump rose (trunk shape 0.37 of its radius against 0.30): the
    first run is kept."""
    trunk = result.trunk_length_exponent
    holdable = solver.trunk_hold == "when-needed" and solver.trunk_stretch != "off" and solver.transform == "per-axis"
    if trunk is None or not holdable or abs(trunk - 1.0 / 3.0) <= TRUNK_LENGTH_RETRY:
        return result
    log.warning("the run met its targets with the trunk's length at exponent %.3f (isometric 0.333, made again "
                "beyond ±%g); trying again with it held isometric by a soft term", trunk, TRUNK_LENGTH_RETRY)
    held = run_with(replace(solver, trunk_hold="on"))
    nearer = held.trunk_length_exponent is not None and abs(held.trunk_length_exponent - 1 / 3) < abs(trunk - 1 / 3)
    if held.converged and nearer and _trunk_shape_worse(held, result):
        result.warnings.append(f"the trunk's length reached exponent {trunk:.3f} (isometric 0.333); held isometric "
                               f"by a soft term it reached {held.trunk_length_exponent:.3f}, but the trunk then "
                               f"changed shape by {100 * held.trunk_shape:.0f}% of its radius beyond a stretch "
                               f"against {100 * result.trunk_shape:.0f}% (a hump, a sag or a bulge): the run as first "
                               "made is kept")
        log.warning("%s", result.warnings[-1])
        return result
    if held.converged and nearer:
        held.warnings.insert(0, f"the run met every target with the trunk's length at exponent {trunk:.3f} "
                                f"(isometric 0.333); made again with it held isometric by a soft term "
                                f"(solver.trunk_hold), it reached {held.trunk_length_exponent:.3f}")
        log.warning("%s", held.warnings[0])
        return held
    why = (held.messages[0] if held.messages else "a target missed") if not held.converged else (
        f"its trunk reached {held.trunk_length_exponent:.3f}")
    result.warnings.append(f"the trunk's length reached exponent {trunk:.3f}, beyond ±{TRUNK_LENGTH_RETRY} of "
                           f"isometric's 0.333 (within the tolerance ±{TRUNK_LENGTH_TOLERANCE}); held by a soft "
                           f"term the run did no better ({why}): the animal's trunk may look "
                           + ("longer" if trunk_longer(trunk, result.target_mass_ratio) else "shorter"))
    log.warning("%s", result.warnings[-1])
    return result


# A run made again with its trunk held is not kept where its trunk's shape (measure/quality.trunk_shape_change,
# in units of the trunk's radius) is beyond the warning's level and more than this further from a
# stretch of the input's than the first run's: the real horse at ×0.5 held sagged and raised its rump
# (0.37 against 0.30). Below the warning the held trunk's length wins: the wolf held measured 0.19-0.22
# against 0.14-0.16 as first made (trunk 0.389), the giraffe 390 at ×0.5 0.15 against 0.12 (0.261).
TRUNK_SHAPE_SLACK = 0.03


def _trunk_shape_worse(held: BiologyScalingResult, first: BiologyScalingResult) -> bool:
    """Whether ``held``'s trunk is humped (its shape change beyond a stretch above
    TRUNK_SHAPE_WARNING) and by more than TRUNK_SHAPE_SLACK over ``first``'s (False where either
    could not be measured)."""
    if held.trunk_shape is None or first.trunk_shape is None:
        return False
    return held.trunk_shape > max(TRUNK_SHAPE_WARNING, first.trunk_shape + TRUNK_SHAPE_SLACK)


def _more_variables(solver, missed: tuple[str, ...] = ()) -> list[tuple[str, str, dict[str, str]]]:
    """The tries a missed run is made again with, in order, as (setting, what it is, the solver
    settings it changes), each change kept for the tries after it: the limbs' thickness; then the
    trunk's length held isometric, δ its lever; then δ free (the hold off). Both along the forward
    axis: per-axis transform only; neither when δ is off.

    A run that met every target but the trunk's length, its shape perhaps missed with it (``missed``,
    :func:`allorules.runs.results.trunk_only`), starts with the hold alone, then κ and the hold
    together, then κ alone (which rarely moves the trunk: the real horse at ×2, 0.437 with it and
    without). Held alone, the real horse at ×2 converges with its hooves in proportion (×1.27-1.39,
    trunk 0.386), where κ with the hold thinned the legs Eq. 9 had thickened and left the hooves
    ×1.68-2.06; the bull 386 and the donkey 385 at ×2 and the pig 383 at ×0.5 converge held alone
    too; the Princeton horse 382 at ×0.5, whose held run misses (0.233), converges with the pair."""
    thickness = {"limb_thickness": "on"} if solver.limb_thickness == "when-needed" else {}
    holding = solver.trunk_stretch != "off" and solver.transform == "per-axis" and solver.trunk_hold == "when-needed"
    more = []
    if holding and trunk_only(missed):
        more.append(("trunk_hold", "the trunk's length held isometric by a soft term",
                     {"limb_thickness": "off", "trunk_hold": "on"} if thickness else {"trunk_hold": "on"}))
        if thickness:
            more.append(("trunk_hold", "the limbs' thickness and the trunk's length held isometric by a soft term",
                         {**thickness, "trunk_hold": "on"}))
            more.append(("limb_thickness", "the limbs' thickness as one more variable", {**thickness, "trunk_hold": "off"}))
    else:
        if thickness:
            more.append(("limb_thickness", "the limbs' thickness as one more variable", thickness))
        if holding:
            more.append(("trunk_hold", "the trunk's length held isometric by a soft term", {"trunk_hold": "on"}))
    if solver.trunk_stretch == "when-needed" and solver.transform == "per-axis":
        # the hold had its own try before
        more.append(("trunk_stretch", "the trunk's length along the body as one more variable",
                     {"trunk_stretch": "on", **({"trunk_hold": "off"} if holding else {})}))
    return more


def place(body: Body, result: Result, placement: str = "ground") -> tuple[Result, str]:
    """The result moved rigidly so that its feet stand on ``body``'s ground plane at the same place
    (``"ground"``), or left with its centroid in place (``"centroid"``). Returns the result and how
    it was placed; a body whose up direction is unknown (no labels, no frame) keeps its centroid,
    and says so."""
    if placement not in PLACEMENTS:
        raise ValueError(f"placement must be one of {', '.join(PLACEMENTS)}, not {placement!r}")
    if placement == "centroid":
        return result, "centroid"
    try:
        contact = ground_contact(body)
    except GroundError as error:
        log.info("placement: %s; the output keeps its centroid in place", error)
        return result, "centroid (up unknown)"
    result.body = result.body.with_vertices(place_on_ground(body, result.body.vertices, contact=contact))
    return result, "ground"


# ---------------------------------------------------------------------------------------------
# A run


@dataclass
class Run:
    """One run: the prepared input, its working mesh, the labelled working body, what was asked and
    what came out (``result.body``: the working body scaled and placed)."""

    prepared: PreparedMesh
    body: Body
    scaling: Scaling
    result: Result
    labels_file: Path | None = None
    placement: str = "ground"            # how the output was placed (see :func:`place`)
    working: Working | None = None       # None: the prepared body itself
    _quality: QualityReport | None = field(default=None, repr=False)
    _carried: tuple[Body, Unfolding] | None = field(default=None, repr=False)

    @property
    def converged(self) -> bool:
        return bool(self.result.converged)

    def missed(self) -> str:
        """What a run that did not converge missed, in one line (the front ends add where its mesh went)."""
        what = f"ruleset {self.scaling.ruleset.name!r}" if hasattr(self.scaling, "ruleset") else "the global run"
        first = self.result.messages[0] if self.result.messages else "a target missed"
        ratio = getattr(self.scaling, "mass_ratio", None)
        settle = self.result.settle() if isinstance(self.result, BiologyScalingResult) else None
        return (f"{what} did not reach its targets" + (f" at mass ratio {ratio:g}" if ratio else "") + f": {first}"
                + (f"; {settle}" if settle else ""))

    def body_vertices(self) -> np.ndarray:
        """The scaled positions of the user's prepared body (carried from the working mesh), every
        face the run folded smoothed back (:meth:`unfolding`)."""
        return self.unfolding().vertices

    def unfolding(self) -> Unfolding:
        """The user's body as the run left it, with the faces it turned inside out smoothed back
        into the surface (:func:`allorules.mesh.unfold.unfold_faces`); not for raw Eq. 4, which
        writes what the user's α and s give. Once per result body (the report's quality and the
        file written both need it)."""
        if self._carried is None or self._carried[0] is not self.result.body:
            if self.working is None:
                before, faces, after = self.body.vertices, self.body.faces, self.result.body.vertices
            else:
                before, faces = self.prepared.vertices, self.prepared.faces
                after = self.working.to_user(self.body.vertices, self.result.body.vertices, self.prepared.vertices)
            raw = isinstance(self.result, RawGlobalResult)
            self._carried = (self.result.body, Unfolding(after, 0, 0, 0, 0.0) if raw else unfold_faces(before, after, faces))
        return self._carried[1]

    def output_vertices(self) -> np.ndarray:
        """The scaled positions of every vertex of the input, in the input's own order."""
        return self.prepared.source_positions(self.body_vertices())

    def report(self) -> dict[str, Any]:
        """The run as JSON: the input, its repairs, who labelled it, and the result's figures."""
        prepared = self.prepared
        document: dict[str, Any] = {
            "allorules": __version__,
            "input": str(prepared.source_path) if prepared.source_path else None,
            "vertices": int(len(prepared.vertices)),
            "faces": int(len(prepared.faces)),
            "repairs": list(prepared.repairs),
            "working_mesh": self.working.report() if self.working else None,
            "labels": _labels_report(self.body),
        }
        document.update(self.result.as_dict())
        if isinstance(self.scaling, GlobalScaling):
            document.update(_independent_check(self.body, self.result))
        document["placement"] = self.placement
        document["quality"] = self.quality().as_dict()
        return document

    def user_body(self) -> Body:
        """The user's prepared body with the run's regions (each vertex takes its working triangle's)."""
        if self.working is None:
            return self.body
        return self.working.labels_to_user(self.body, Body(self.prepared.vertices, self.prepared.faces))

    def _written(self) -> tuple[Body, np.ndarray]:
        """The user's body with the run's regions and where the run moved it; for an animal in
        pieces, the pieces themselves (their faces are what is written, not the joined surface's),
        but for the faces buried in the body, which nobody sees."""
        user = self.user_body()
        if self.prepared.pieces is None:
            return user, self.body_vertices()
        source = self.prepared.source
        seen = np.asarray(source.faces, dtype=np.int64)[~self.prepared.pieces.buried]
        labels = None if user.labels is None else self.prepared.source_labels(user.labels)   # raw Eq. 4: none
        pieces = Body(np.asarray(source.vertices, dtype=float), seen, labels, user.region_names)
        return pieces, self.output_vertices()

    def quality(self) -> QualityReport:
        """What an artist would look for in the output (flipped faces, self-intersections, lumps,
        small features, legs, rules met), measured once."""
        if self._quality is None:
            self._quality = quality_report(self.body, self.result.body.vertices, rules=getattr(self.result, "rules", None),
                                           tolerance=EXPONENT_TOLERANCE)
            unfolding = self.unfolding()
            carried = self.working is not None and self.working.binding is not None
            if carried or unfolding.folded or self.prepared.pieces is not None:
                # measured on the working mesh (or before unfolding); the faces written counted too
                self._quality.written_flipped = flipped_faces(*self._written())
                self._quality.unfolded = unfolding.unfolded
                self._quality.unfold_move = unfolding.largest_move / max(float(np.ptp(unfolding.vertices, axis=0).max()), 1e-300)
        return self._quality


def run(
    source: str | Path | Any,
    scaling: Scaling,
    *,
    registry: PluginRegistry | None = None,
    labels: str | Path | VertexRegions | None = None,
    segmenter: SegmenterUse | None = None,
    up: np.ndarray | None = None,
    forward: np.ndarray | None = None,
    modes: int | None = None,
    use_cache: bool = True,
    progress: RunProgress | None = None,
    placement: str = "ground",
    working_vertices: int | None = None,
    labels_beside: bool = True,
) -> Run:
    """Prepare, label, scale and place ``source`` (a mesh file, a ``trimesh.Trimesh`` or a
    :class:`Body`; a labelled ``Body`` keeps its labels). The segmenter is ``segmenter``, else the
    ruleset's, else ``auto-quadruped``; ``labels`` (a file for the user's prepared body, or
    :class:`VertexRegions` for the input's vertices) replaces it. ``placement``: ``"ground"`` (the
    output's feet where the input's were) or ``"centroid"``.
    ``working_vertices``: the working mesh's size (default
    :data:`allorules.mesh.working.WORKING_VERTICES`; a body at or below it is used as it is).
    ``labels_beside``: with no ``labels``, a mesh file's own ``NAME.labels.json`` beside it is read
    where it fits the mesh (:func:`labelled_working`); ``False`` labels it afresh."""
    registry = registry if registry is not None else registry_for(None)
    check_working_vertices(working_vertices)            # before any work
    ruleset = scaling.ruleset if isinstance(scaling, RulesetScaling) else None
    prepared = prepare(source)
    given = source if isinstance(source, Body) and source.labels is not None else None
    segmenter = segmenter or (ruleset.segmenter if ruleset else None)
    regions = wanted_regions(ruleset)
    if isinstance(scaling, RawGlobalScaling) and labels is None and given is None:
        work = working(prepared, working_vertices)
        body = work.body()                              # Eq. 4 once measures nothing: no regions needed
    else:
        work, body = labelled_working(prepared, registry=registry, working_vertices=working_vertices,
                                      segmenter=segmenter, labels=labels, given=given, up=up, forward=forward,
                                      regions=regions, labels_beside=labels_beside)
    labels_file = Path(labels) if isinstance(labels, (str, Path)) else None
    try:
        result = scale(body, scaling, registry=registry, modes=modes, use_cache=use_cache, progress=progress)
        if not result.converged and ruleset is not None and working_vertices is None:
            if work.mesh.is_coarse_source:
                work, body, result = _split_working(prepared, work, body, result, scaling, registry=registry,
                                                    modes=modes, use_cache=use_cache, progress=progress)
            else:
                work, body, result = _coarser_working(prepared, work, body, result, scaling, registry=registry,
                                                      modes=modes, use_cache=use_cache, progress=progress,
                                                      regions=regions, segmenter=segmenter, up=up, forward=forward)
    except ScalingError as error:
        if isinstance(error.closest, BiologyScalingResult) and error.run is None:
            # a run that stopped at a step: what it reached, placed, goes with the error, so that a
            # front end can still write its report and its picture (issue 18 §4)
            try:
                reached, placed = place(body, error.closest, placement)
            except AllorulesError:
                raise error from None       # what stopped the run is what the user is told
            error.run = Run(prepared, body, scaling, reached, labels_file, placed, _kept(work))
        raise
    result, placed = place(body, result, placement)
    return Run(prepared, body, scaling, result, labels_file, placed, _kept(work))


def _kept(work: Working) -> Working | None:
    """The working mesh a :class:`Run` keeps: none for the body itself, unless it was tried on others."""
    return None if work.binding is None and not work.also_tried else work


def _coarser_working(prepared: PreparedMesh, work: Working, body: Body, result: Result, scaling: RulesetScaling, *,
                     registry: PluginRegistry, modes: int | None, use_cache: bool, progress: RunProgress | None,
                     regions: tuple[str, ...], segmenter: SegmenterUse | None, up: np.ndarray | None,
                     forward: np.ndarray | None) -> tuple[Working, Body, Result]:
    """A ruleset run that missed on the default working mesh, made again on coarser ones
    (:data:`COARSER_WORKING`, in turn) until one converges: labelled there by the segmenter as
    a run at that ``--working-vertices`` is (a segmenter refusing there ends the tries), or with
    regions the user gave, carried across. Where a run ends turns on the working mesh it solves
    on: a held-out donkey split to 136k, missed at 8,000 and 4,000, converged at 2,500 labelled
    there, not with the 8,000's regions carried (docs/working-mesh.md). Not for a working mesh a
    labels file recorded or a size the user chose. Where every one misses, the default's run is
    kept. The working mesh kept names the others it was tried on (``also_tried``)."""
    if work.mesh.method == "recorded":
        return work, body, result
    segmented = body.labelling is not None and body.labelling.source.startswith("segmenter")
    user = None if segmented else work.labels_to_user(body, Body(prepared.vertices, prepared.faces))
    tries = [WorkingTry(int(len(work.mesh.vertices)), _first_message(result))]
    for size in COARSER_WORKING:
        if min(attempt.vertices for attempt in tries) <= size * 1.25:   # hardly coarser: the same run again
            continue
        log.warning("the run on a working mesh of %d vertices missed its targets (%s); making it again on a coarser "
                    "one of about %d vertices, %s", tries[-1].vertices, tries[-1].missed, size,
                    "labelled there" if segmented else "with your regions")
        coarser = working(prepared, size)
        try:
            coarser_body = (label_working(prepared, coarser, registry=registry, segmenter=segmenter, up=up,
                                          forward=forward, regions=regions) if segmented
                            else _framed(fold_regions(coarser.from_user(user), regions), given=True))
        except SegmentationError as error:   # the regions cannot be told there: the default's run stands
            tries.append(WorkingTry(int(len(coarser.mesh.vertices)), f"not labelled: {error}"))
            log.warning("on the coarser working mesh the regions were not found: %s", error)
            break
        try:
            coarser_result = scale(coarser_body, scaling, registry=registry, modes=modes, use_cache=use_cache,
                                   progress=progress)
        except ScalingError as error:      # a step stopped there: the default's run stands
            tries.append(WorkingTry(int(len(coarser.mesh.vertices)), str(error)))
            log.warning("on the coarser working mesh the run stopped: %s", error)
            break
        if coarser_result.converged:
            log.warning("made again on a working mesh of %d vertices, the run converged", len(coarser.mesh.vertices))
            return replace(coarser, also_tried=tuple(tries)), coarser_body, coarser_result
        tries.append(WorkingTry(int(len(coarser.mesh.vertices)), _first_message(coarser_result)))
    return replace(work, also_tried=tuple(tries[1:])), body, result


def _split_working(prepared: PreparedMesh, work: Working, body: Body, result: Result, scaling: RulesetScaling, *,
                   registry: PluginRegistry, modes: int | None, use_cache: bool,
                   progress: RunProgress | None) -> tuple[Working, Body, Result]:
    """A ruleset run that missed on a coarse body used as it is (under ``SPLIT_BELOW`` vertices),
    made again on the body split finer (``split_working_mesh``: the same surface), with the regions
    it had carried across: the labeller keeps reading the body as it comes. Kept where it
    converges; else the first run stands. Measured (docs/benchmarks.md, "Coarse bodies split
    finer"): two held-out low-poly animals that missed at ×0.5 (a fox and a running cat) converge
    split; split from the start, a goat at ×0.5 came out lumpy and a tiger was refused where as
    they come they converged, so the split is a second try, not the first."""
    finer = split_working_mesh(prepared.vertices, prepared.faces)
    first = WorkingTry(int(len(work.mesh.vertices)), _first_message(result))
    log.warning("the run on the body as it is (%d vertices) missed its targets (%s); making it again on the body "
                "split at its edges' midpoints (%d vertices, the same surface), with its regions",
                first.vertices, first.missed, len(finer.vertices))
    split = Working(finer, bind(prepared.vertices, finer.vertices, finer.faces))
    split_body = _framed(split.from_user(body), given=True)
    try:
        split_result = scale(split_body, scaling, registry=registry, modes=modes, use_cache=use_cache,
                             progress=progress)
    except ScalingError as error:      # a step stopped there: the first run stands
        log.warning("on the body split finer the run stopped: %s", error)
        return replace(work, also_tried=(WorkingTry(int(len(finer.vertices)), str(error)),)), body, result
    if split_result.converged:
        log.warning("made again on the body split finer (%d vertices), the run converged", len(finer.vertices))
        return replace(split, also_tried=(first,)), split_body, split_result
    return replace(work, also_tried=(WorkingTry(int(len(finer.vertices)), _first_message(split_result)),)), body, result


def _first_message(result: Result) -> str:
    return result.messages[0] if result.messages else "a target missed"


def save_output(run: Run, path: str | Path, *, overwrite: bool = False) -> SaveResult:
    """Write the run's output mesh in the input's own layout (UVs, materials, detached parts kept)
    and, where the run had regions, the regions it measured as the output's own labels file beside
    it (``NAME.labels.json``), so that the output is measured again with the run's regions and
    axes, not relabelled as another animal; the input is never overwritten. ``save_mesh`` says on
    the log what the export could not carry over. An animal in pieces gets no labels file: its
    output is joined afresh when read, into a surface of other vertices than the input's."""
    prepared = run.prepared
    labels = labels_file_beside(path) if run.body.labels is not None and prepared.pieces is None else None
    if prepared.pieces is not None:
        log.info("no labels file beside %s: an animal in pieces is joined afresh when read (allorules measure "
                 "labels it again; give it --forward if its input needed it)", path)
    if labels is not None:      # checked before anything is written
        _check_output_labels(run, labels, overwrite)
    if prepared.source is not None:
        saved = save_mesh(path, run.output_vertices(), np.asarray(prepared.source.faces), source=prepared.source,
                          input_path=prepared.source_path, overwrite=overwrite)
    else:
        saved = save_mesh(path, run.body_vertices(), prepared.faces, input_path=prepared.source_path,
                          overwrite=overwrite)
    if labels is not None:      # the tape as the run put it on its input, and the working mesh it measured on
        carried = run.working is not None and run.working.binding is not None
        record = WorkingRecord.of(run.working.mesh, prepared.vertices, prepared.faces, run.body.labels) if carried else None
        write_labels(labels, replace(run.user_body(), tape=heart_girth_tape(run.body)), record)
        log.info("wrote %s: the regions the run measured, which allorules measure reads", labels)
    return saved   # save_mesh has said what it could not carry over (saved.notes), once


def _check_output_labels(run: Run, labels: Path, overwrite: bool) -> None:
    """An output's labels file never replaces the run's own labels (its labels file, its input's
    labels file beside it), and another file only with ``overwrite``."""
    beside = labels_file_beside(run.prepared.source_path) if run.prepared.source_path else None
    for given in (run.labels_file, beside if beside is not None and beside.is_file() else None):
        if given is not None and same_file(labels, Path(given)):
            raise OutputError(f"{labels}: the output's labels file would replace the input's labels "
                              f"{given}; choose another output name")
    if labels.exists() and not overwrite:
        raise OutputError(f"{labels}: already exists (the output's labels file); choose another output name "
                          "or pass --force")


def save_picture(run: Run, path: str | Path, *, output_name: str = "output") -> Path:
    """The input and the output side by side, at true relative size, as they stand in one scene (an
    output that floats or sinks is drawn so)."""
    from allorules.output.render import render_comparison

    body = run.body
    if run.prepared.pieces is not None:
        # an animal in pieces: its working surface is the solid they enclose, not what the user
        # modelled; draw the pieces themselves, as they are written
        source = run.prepared.source
        before, faces, after = np.asarray(source.vertices), np.asarray(source.faces), run.output_vertices()
    else:
        before, faces, after = body.vertices, body.faces, run.result.body.vertices
    return render_comparison([(before, faces, "input"), (after, faces, output_name)],
                             path=path, normalise_size=False, frame=body.frame, shared_ground=True)


# ---------------------------------------------------------------------------------------------
# Report helpers


def _labels_report(body: Body) -> dict[str, Any]:
    """Who labelled the body, how sure it was, and each region's share of the surface."""
    labelling = body.labelling.as_dict() if body.labelling else {"source": "given", "confidence": {}, "notes": []}
    if body.labels is not None:
        area = vertex_areas(body.vertices, body.faces)
        shares = np.bincount(body.labels[body.labels >= 0], weights=area[body.labels >= 0],
                             minlength=len(body.region_names)) / area.sum()
        labelling["regions"] = {name: round(float(share), 4) for name, share in zip(body.region_names, shares)}
    return labelling


def _independent_check(body: Body, result: ScalingResult) -> dict[str, Any]:
    """Mass and peak stress of a global run's output measured from scratch (new contours, new choice)."""
    fresh_in = Body(body.vertices, body.faces, body.labels, body.region_names, body.frame)
    fresh_out = Body(result.body.vertices, body.faces, body.labels, body.region_names, body.frame)
    check: dict[str, Any] = {"mass_ratio_measured": body_mass(fresh_out) / body_mass(fresh_in)}
    try:
        check["stress_ratio_reselected"] = peak_stress(fresh_out) / peak_stress(fresh_in)
    except MeasurementError as error:
        check["stress_ratio_reselected"] = None
        check["messages"] = list(result.messages) + [f"independent stress check failed: {error}"]
    return check


__all__ = ["GlobalScaling", "RulesetScaling", "RawGlobalScaling", "LocalScaling", "Scaling", "Run", "prepare",
           "label", "label_working", "labelled_working", "read_labels_beside", "scale", "place", "PLACEMENTS", "working",
           "Working", "run", "save_output", "save_picture", "wanted_regions"]
