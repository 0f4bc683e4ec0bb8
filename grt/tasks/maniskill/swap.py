"""Swap one actor of any ManiSkill env for a candidate mesh, inside the env's own (re)configuration.

:class:`ActorSwap` intercepts ``ActorBuilder.build`` (ManiSkill's, process-wide, once) for the builder whose
name matches the task's ``actor`` (an exact name or a regex, ``re.fullmatch``) while *its* env loads its
scene. The builder keeps everything the env gave it — name, body type, initial pose, ``scene_idxs``,
collision groups, mass settings — and gets, instead of its collision records, the candidate's convex
parts (``physx.PhysxCollisionShapeConvexMesh`` from vertex arrays, each part with the density, material
and patch radii of the stock record nearest it) and, instead of its visuals, the candidate's mesh
(``render.RenderShapeTriangleMesh``, coloured as the stock visual). With no candidate loaded the stock
actor is built as the env made it, and its records are kept (the nominal geometry of that build).

Batched from the start: candidates are held per sub-scene index (:meth:`ActorSwap.set_candidates`). A
builder that spans sub-scenes holding different candidates is split into one builder per sub-scene
(``set_scene_idxs([i])``) and the actors merged under the env's name (``Actor.merge``, as ManiSkill's
``pick_single_ycb.py`` does); on the CPU backend (one sub-scene) there is one candidate and one build.

Hooks on the env instance (:meth:`ActorSwap.attach`), so that whoever resets the env — the session, or a
policy that drives the env itself (a motion planner's ``solve(env, seed)``) — gets the candidate:

- ``_load_scene``: the interception is on while the env builds its scene (every reconfigure: envs that
  rebuild at every reset, such as PegInsertionSide, get the candidate at every rebuild). An env that draws
  the actor's size at each rebuild gets the candidate scaled per axis by this build's stock extents over
  the reference build's (the first one), so the candidate follows the env's own size randomization.
- ``_initialize_episode``: after the env placed the actor (by its *stock* size), **settle**: the candidate is
  moved up or down so that its lowest point is where the stock actor's was at that pose: a taller cube does
  not start inside the table, and a shorter one, or a polyhedral sphere (whose lowest point is a hair above
  the sphere's), does not start in the air and drop.
- ``evaluate``: the **refresh** (the task's ``refresh`` function, :mod:`grt.tasks.maniskill.refresh`) sets
  the attributes the env's success check reads from the candidate's geometry (``cube_half_size``,
  ``peg_head_offsets``, ...) before every check; the stock values are put back before the env loads a
  scene or places an episode, so the env's own logic always sees its stock numbers.
"""

from __future__ import annotations

import copy
import logging
import re
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np
import trimesh

from grt.tasks.maniskill.geometry import (
    ROUND_WEDGES,
    ActorGeometryError,
    ShapeRecord,
    is_round,
    nearest_records,
    read_records,
    records_mesh,
    round_wedges,
)

log = logging.getLogger(__name__)

_ACTIVE: list[ActorSwap] = []  # the swap whose env is loading its scene now (a stack: one env per process)
_ORIGINAL_BUILD = None


def _install() -> None:
    """Route ManiSkill's ``ActorBuilder.build`` through the active swap (once per process)."""
    global _ORIGINAL_BUILD
    from mani_skill.utils.building.actor_builder import ActorBuilder

    if _ORIGINAL_BUILD is not None:
        return
    _ORIGINAL_BUILD = ActorBuilder.build

    def build(self, name):
        if _ACTIVE:
            return _ACTIVE[-1].build(self, name)
        return _ORIGINAL_BUILD(self, name)

    ActorBuilder.build = build


@dataclass
class Candidate:
    """A candidate object in the actor frame of the reference build (m).

    Attributes:
        mesh: the visual mesh; parts: convex collision parts, each ``(K, 3)``.
    """

    mesh: trimesh.Trimesh
    parts: list[np.ndarray]


@dataclass
class Build:
    """One build of a matching actor in the current scene.

    Attributes:
        name: the builder's name; scene_idxs: the sub-scenes it spans.
        records: the stock collision records; stock: their solid (actor frame, m).
        actor: the ManiSkill ``Actor`` built; scale: ``(3,)`` per-axis scale applied to the candidate.
        hulls: per sub-scene of ``scene_idxs``, ``(K, 3)`` actor-frame points of what was built (the
            candidate's part vertices, or the stock solid's vertices when no candidate).
        swapped: whether the candidate was built (else the stock actor).
    """

    name: str
    scene_idxs: list[int]
    records: list[ShapeRecord]
    stock: trimesh.Trimesh
    actor: object = None
    scale: np.ndarray = field(default_factory=lambda: np.ones(3))
    hulls: list[np.ndarray] = field(default_factory=list)
    swapped: bool = False


class RefreshError(RuntimeError):
    """A refresh function that returned something the env cannot use (a trial's ``sim_error``, naming it)."""


def refreshed(refresh: Callable, env, swap) -> dict:
    """``refresh(env, swap)``, checked: a mapping of the env's attribute names to finite numbers or arrays.

    Raises:
        RefreshError: names the function, what it returned and what it must return.
    """
    name = f"task.session.refresh={getattr(refresh, '__module__', '?')}.{getattr(refresh, '__qualname__', refresh)}"
    out = refresh(env, swap)
    if not isinstance(out, dict):
        raise RefreshError(f"{name} returned a {type(out).__name__}; it must return a dict {{attribute: value}} of "
                           "the env's attributes its success check reads")
    for attr, value in out.items():
        if not isinstance(attr, str) or not hasattr(env, attr):
            raise RefreshError(f"{name} returned the key {attr!r}, which is no attribute of {type(env).__name__}; "
                               "its keys must be attributes the env's success check reads")
        array = _numbers(value)
        if array is not None and not np.all(np.isfinite(array)):
            raise RefreshError(f"{name} returned {attr}={array.tolist()} (not finite): every trial's success check "
                               "would read it; return finite sizes computed from swap's hulls")
    return out


def _numbers(value) -> np.ndarray | None:
    """A refreshed value's numbers (a number, array, tensor or ManiSkill ``Pose``), ``None`` for anything else."""
    value = getattr(value, "raw_pose", value)  # a Pose: its (n, 7) position and quaternion
    try:
        return np.asarray(value.detach().cpu() if hasattr(value, "detach") else value, dtype=np.float64)
    except (TypeError, ValueError):
        return None


class ActorSwap:
    """Builds one named actor of an env from a candidate mesh; see the module docstring.

    Args:
        actor: the actor's builder name, exact or a regex (``peg_\\d+``), matched with ``re.fullmatch``.
        refresh: ``refresh(env, swap) -> {attribute: value}``, the attributes the env's success check reads,
            computed from the candidate's geometry (``None``: nothing to refresh).
        round_wedges: surface caps of the candidate's mesh added to a round actor's parts
            (:func:`~grt.tasks.maniskill.geometry.round_wedges`; 0: the parts alone).
    """

    def __init__(self, actor: str, refresh: Callable[[object, ActorSwap], dict] | None = None,
                 round_wedges: int = ROUND_WEDGES):
        self.pattern = re.compile(str(actor))
        self.refresh = refresh
        self.round_wedges = int(round_wedges)
        self.candidates: dict[int, Candidate] = {}
        self.reference: trimesh.Trimesh | None = None  # the first build's stock solid (actor frame)
        self.reference_solids: list[trimesh.Trimesh] = []  # ... and its records' solids, one per record
        self.builds: list[Build] = []
        self.names: list[str] = []  # every actor name built in the last scene (for messages)
        self.env = None
        self.mass_source = "stock"  # where the last build's mass came from: stock | mesh | env | parts (why)
        self._saved: dict[str, object] = {}
        _install()

    # ------------------------------------------------------------------ candidates
    def set_candidates(self, candidates: dict[int, Candidate] | Candidate | None) -> None:
        """The candidate of each sub-scene (one :class:`Candidate` for all; ``None`` or ``{}``: the stock
        actor). Takes effect at the env's next (re)configuration."""
        if isinstance(candidates, Candidate):
            candidates = {-1: candidates}
        self.candidates = dict(candidates or {})

    def candidate(self, scene_idx: int) -> Candidate | None:
        return self.candidates.get(int(scene_idx), self.candidates.get(-1))

    def matches(self, name: str) -> bool:
        return self.pattern.fullmatch(name) is not None

    @property
    def swapped(self) -> bool:
        """Whether the current scene holds a candidate (not the stock actor)."""
        return any(b.swapped for b in self.builds)

    # ------------------------------------------------------------------ interception
    @contextmanager
    def active(self) -> Iterator[None]:
        """Intercept the builds of the scene loaded inside this block (a new scene forgets the last builds)."""
        self.builds, self.names = [], []
        _ACTIVE.append(self)
        try:
            yield
        finally:
            _ACTIVE.remove(self)

    def build(self, builder, name: str):
        """The interception of ``ActorBuilder.build`` (see the module docstring)."""
        self.names.append(str(name))
        if not self.matches(str(name)):
            return _ORIGINAL_BUILD(builder, name)
        records = read_records(builder)
        try:
            stock = records_mesh(records)
        except ActorGeometryError as err:  # a regex (".*") that caught the ground or a marker: name the catch
            raise ActorGeometryError(f"task.session.actor={self.pattern.pattern} matched the actor {name!r}: {err}; if it is "
                                     "not the actor to deform, name that one exactly") from None
        if self.reference is None:
            self.reference = stock
            self.reference_solids = [r.mesh for r in records if r.mesh is not None]
        num = builder.scene.num_envs
        idxs = [int(i) for i in (range(num) if builder.scene_idxs is None else list(builder.scene_idxs))]
        scale = np.asarray(stock.extents, np.float64) / np.maximum(np.asarray(self.reference.extents), 1e-12)
        chosen = [self.candidate(i) for i in idxs]
        rec = Build(str(name), idxs, records, stock, scale=scale)
        if all(c is None for c in chosen):
            rec.actor = _ORIGINAL_BUILD(builder, name)
            rec.hulls = [np.asarray(stock.vertices) for _ in idxs]
        elif all(c is chosen[0] for c in chosen):
            rec.actor, hull = self._build_one(builder, name, chosen[0], records, scale)
            rec.hulls, rec.swapped = [hull for _ in idxs], True
        else:
            rec.actor, rec.hulls = self._build_per_scene(builder, name, idxs, chosen, records, scale, stock)
            rec.swapped = True
        self.builds.append(rec)
        return rec.actor

    def _build_per_scene(self, builder, name, idxs, chosen, records, scale, stock):
        """One builder per sub-scene (its own candidate), merged under the env's name (GPU backend)."""
        from mani_skill.utils.structs.actor import Actor
        from mani_skill.utils.structs.pose import Pose

        pose = Pose.create(builder.initial_pose) if builder.initial_pose is not None else None
        actors, hulls = [], []
        for k, (i, cand) in enumerate(zip(idxs, chosen, strict=True)):
            one = copy.copy(builder)
            one.collision_records, one.visual_records = list(builder.collision_records), list(builder.visual_records)
            one._procedural_shapes = list(builder._procedural_shapes)
            one.set_scene_idxs([i])
            if pose is not None:
                one.initial_pose = Pose.create(pose.raw_pose[k if len(pose.raw_pose) > 1 else 0])
            if cand is None:
                actor, hull = _ORIGINAL_BUILD(one, f"{name}-scene{i}"), np.asarray(stock.vertices)
            else:
                actor, hull = self._build_one(one, f"{name}-scene{i}", cand, records, scale)
            builder.scene.remove_from_state_dict_registry(actor)
            actors.append(actor)
            hulls.append(hull)
        merged = Actor.merge(actors, name)
        builder.scene.add_to_state_dict_registry(merged)
        return merged, hulls

    def _build_one(self, builder, name, cand: Candidate, records: list[ShapeRecord], scale: np.ndarray):
        """Build ``cand`` (scaled per axis by ``scale``) with the builder's settings; returns (actor, hull points)."""
        from grt.tasks.scene import attach_convex_parts, render_mesh_shape

        parts = [np.asarray(p, np.float64) * scale for p in cand.parts]
        if self.round_wedges and is_round(records):  # a round actor: its parts and fine caps of its own mesh
            parts += round_wedges(np.asarray(cand.mesh.vertices) * scale, max(len(p) for p in parts),
                                  self.round_wedges)
        owners = nearest_records(parts, records)
        colour = _stock_colour(builder)
        props = self._mass_properties(builder, cand, records, scale)
        builder.collision_records, builder.visual_records = [], []
        if builder.scene.can_render():
            mesh = cand.mesh.copy()
            mesh.vertices = np.asarray(mesh.vertices) * scale
            builder._procedural_shapes = [*builder._procedural_shapes, render_mesh_shape(mesh, colour)]
        stock_component = builder.build_physx_component
        counted = []

        def build_physx_component(link_parent=None):
            component = stock_component(link_parent)
            built = 0
            for part, k in zip(parts, owners, strict=True):
                r = records[k]
                built += attach_convex_parts(component, [part], r.material, r.density, builder.collision_groups)
                for shape in component.collision_shapes[-1:]:
                    shape.set_patch_radius(r.patch_radius)
                    shape.set_min_patch_radius(r.min_patch_radius)
            counted.append(built)
            if props is not None:
                component.set_mass(props[0])
                component.set_cmass_local_pose(props[1])
                component.set_inertia(props[2])
            return component

        builder.build_physx_component = build_physx_component
        actor = _ORIGINAL_BUILD(builder, name)
        if not counted or min(counted) != len(parts):
            raise ValueError(f"only {min(counted or [0])} of {len(parts)} collision parts of {name!r} were built")
        return actor, np.concatenate(parts)

    def _mass_properties(self, builder, cand: Candidate, records: list[ShapeRecord], scale: np.ndarray):
        """``(mass, cmass pose, principal moments)`` to give the candidate's body (:mod:`.massprops`): the env's own
        numbers when it set them (``set_mass_and_inertia``), else the candidate's mesh under the records' density
        field; ``None`` for a body without mass (kinematic, static). A mesh that is no closed solid keeps the mass
        PhysX gives its parts, said in :attr:`mass_source`."""
        import sapien

        from grt.tasks.maniskill.massprops import candidate_mass

        if getattr(builder, "physx_body_type", "dynamic") != "dynamic":
            return None
        if not getattr(builder, "_auto_inertial", True):
            self.mass_source = "env"
            return builder._mass, builder._cmass_local_pose, np.asarray(builder._inertia, np.float64)
        solids = [r for r in records if r.mesh is not None]
        mesh = cand.mesh.copy()
        mesh.vertices = np.asarray(mesh.vertices) * scale
        try:
            props = candidate_mass(mesh, [r.mesh for r in solids],
                                   [r.density * r.volume / max(abs(float(r.mesh.volume)), 1e-18) for r in solids])
        except ValueError as err:
            self.mass_source = f"parts ({err})"
            log.warning("the candidate's mesh %s: its body gets the mass of its convex parts", err)
            return None
        self.mass_source = "mesh"
        com, quat, moments = props.principal()
        return float(props.mass), sapien.Pose(com, quat), moments

    # ------------------------------------------------------------------ the env's hooks
    def attach(self, env) -> None:
        """Wrap ``env``'s ``_load_scene``, ``_initialize_episode`` and ``evaluate`` (the instance's, not the
        class's), so that every reset of this env, by whoever, builds, settles and judges the candidate."""
        self.env = env
        load, init, evaluate = env._load_scene, env._initialize_episode, env.evaluate

        def _load_scene(options):
            self.restore()
            with self.active():
                return load(options)

        def _initialize_episode(env_idx, options):
            self.restore()
            init(env_idx, options)
            self.settle(env_idx)
            self.apply()

        def _evaluate(*args, **kwargs):
            self.apply()
            return evaluate(*args, **kwargs)

        env._load_scene, env._initialize_episode, env.evaluate = _load_scene, _initialize_episode, _evaluate

    def settle(self, env_idx) -> list[float]:
        """Move each swapped actor being reset up or down so that the candidate's lowest point is where the stock
        actor's lowest point was at the env's pose (m moved up, per sub-scene; negative: down)."""
        from mani_skill.utils import common
        from mani_skill.utils.structs.pose import Pose

        lifts = []
        reset = {int(i) for i in np.asarray(common.to_numpy(env_idx)).reshape(-1)}
        for b in self.builds:
            if not b.swapped:
                continue
            raw = np.array(common.to_numpy(b.actor.pose.raw_pose), np.float64).reshape(-1, 7)
            rows = [k for k, i in enumerate(b.scene_idxs) if i in reset]
            moved = False
            for k in rows:
                rot = _quat_matrix(raw[k, 3:7])
                stock = _lowest(rot, np.asarray(b.stock.vertices) * 1.0)
                cand = _lowest(rot, b.hulls[k])
                lift = stock - cand
                lifts.append(lift)
                if abs(lift) > 1e-7:
                    raw[k, 2] += lift
                    moved = True
            if moved:
                b.actor.set_pose(Pose.create(common.to_tensor(raw[rows].astype(np.float32), device=b.actor.device)))
        return lifts

    def apply(self) -> None:
        """Set the attributes the env's success check reads from the candidate (see :meth:`restore`)."""
        if self.refresh is None or not self.swapped or self.env is None:
            return
        for attr, value in refreshed(self.refresh, self.env, self).items():
            if attr not in self._saved:
                self._saved[attr] = getattr(self.env, attr)
            setattr(self.env, attr, value)

    def restore(self) -> None:
        """Put back the env's stock values of the refreshed attributes."""
        for attr, value in self._saved.items():
            setattr(self.env, attr, value)
        self._saved = {}

    # ------------------------------------------------------------------ geometry of the current scene
    def build_of(self, scene_idx: int = 0) -> Build:
        """The build of the swapped actor in sub-scene ``scene_idx``."""
        for b in self.builds:
            if scene_idx in b.scene_idxs:
                return b
        raise LookupError(f"no actor matching {self.pattern.pattern!r} was built in sub-scene {scene_idx}")

    def hull(self, scene_idx: int = 0) -> np.ndarray:
        """``(K, 3)`` actor-frame points (m) of what sub-scene ``scene_idx`` holds now (candidate or stock)."""
        b = self.build_of(scene_idx)
        return b.hulls[b.scene_idxs.index(scene_idx)]

    def stock_hull(self, scene_idx: int = 0) -> np.ndarray:
        """``(V, 3)`` actor-frame vertices (m) of the stock actor of sub-scene ``scene_idx``'s build."""
        return np.asarray(self.build_of(scene_idx).stock.vertices)

    def matched(self) -> list[str]:
        """The names of the matching actors built in the last scene."""
        return [b.name for b in self.builds]


def _stock_colour(builder) -> tuple[float, float, float]:
    for r in builder.visual_records:
        mat = getattr(r, "material", None)
        if mat is not None and hasattr(mat, "base_color"):
            return tuple(float(c) for c in list(mat.base_color)[:3])
    return (0.7, 0.7, 0.7)


def _quat_matrix(q: np.ndarray) -> np.ndarray:
    """``(3, 3)`` rotation of a wxyz quaternion."""
    w, x, y, z = np.asarray(q, np.float64) / max(np.linalg.norm(q), 1e-12)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _lowest(rot: np.ndarray, points: np.ndarray) -> float:
    """The lowest z (m, relative to the actor's origin) of actor-frame ``points`` rotated by ``rot``."""
    return float((np.asarray(points, np.float64) @ rot[2]).min())


def depth_below(swap: ActorSwap, rot: np.ndarray, scene_idx: int = 0) -> float:
    """How far (m) the actor's origin sits above its lowest point when turned by ``rot`` (world): the
    height of the origin of the actor resting on a flat surface in that orientation."""
    return -_lowest(rot, swap.hull(scene_idx))


def top_above(points: np.ndarray, rot: np.ndarray) -> float:
    """How far (m) the highest of actor-frame ``points`` turned by ``rot`` is above the origin."""
    return float((np.asarray(points, np.float64) @ rot[2]).max())
