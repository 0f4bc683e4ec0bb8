"""Scene pieces shared by GRT tasks: in-memory object actors, hemisphere depth cameras, point clouds.

SAPIEN caches meshes by file path and skips shapes that fail to cook without a word, and PhysX
inflates degenerate hulls into 2 mm boxes; so objects are built here from vertex arrays in memory,
every collision part is counted, and every cooked hull is compared with its input. On the GPU
(``physx_cuda``) PhysX cooks every hull to at most 64 vertices and 64 polygons, growing a larger one into
a hull that contains it: there a hull may grow by up to :data:`GPU_INFLATION`, and the growth is tallied.
"""

from __future__ import annotations

import numpy as np
import sapien
import trimesh
from mani_skill.sensors.camera import CameraConfig
from mani_skill.utils import sapien_utils
from mani_skill.utils.building.actor_builder import ActorBuilder
from sapien import physx

#: how much (m) a cooked hull's extent may exceed its input's before the part counts as degenerate: on the
#: CPU PhysX cooks a hull as given (a flat or tiny part grows into a ~2 mm box); on the GPU it also grows
#: hulls of more than 64 vertices or polygons into ones that contain them.
CPU_INFLATION, GPU_INFLATION = 5e-4, 5e-3


def new_tally() -> dict:
    """A record of the hulls built: ``parts`` and the largest growth ``max_inflation_m`` PhysX gave one."""
    return {"parts": 0, "max_inflation_m": 0.0}


class InMemoryActorBuilder(ActorBuilder):
    """A ManiSkill actor builder whose collision shapes are convex vertex arrays held in memory.

    Args:
        parts: convex parts, each ``(K, 3)`` vertices (m) in the actor frame, ``K >= 4``.
        material: PhysX material of every part.
        density: kg/m^3 of every part (mass and inertia follow from the parts' volumes).
    """

    def __init__(self, parts: list[np.ndarray], material: physx.PhysxMaterial, density: float,
                 tally: dict | None = None):
        super().__init__()
        self._parts = [np.ascontiguousarray(p, dtype=np.float32).reshape(-1, 3) for p in parts]
        self._material, self._density, self._tally = material, float(density), tally
        self.num_built_shapes = 0

    def build_physx_component(self, link_parent=None):
        component = super().build_physx_component(link_parent)
        gpu = bool(getattr(self.scene, "gpu_sim_enabled", False))
        self.num_built_shapes += attach_convex_parts(component, self._parts, self._material, self._density,
                                                     self.collision_groups, GPU_INFLATION if gpu else CPU_INFLATION,
                                                     self._tally)
        return component


def attach_convex_parts(component, parts: list[np.ndarray], material: physx.PhysxMaterial, density: float,
                        collision_groups, max_inflation: float = CPU_INFLATION, tally: dict | None = None) -> int:
    """Attach convex collision shapes built from vertex arrays to a PhysX body; returns how many.

    ``max_inflation``: the growth (m) of a cooked hull's extent beyond which it counts as degenerate
    (:data:`CPU_INFLATION`, :data:`GPU_INFLATION`); ``tally``: a :func:`new_tally` record to update.

    Raises:
        ValueError: a part with < 4 or non-finite vertices, that PhysX cannot cook, or that PhysX
            inflated (a flat, collinear or sub-millimetre part).
    """
    built = 0
    for i, verts in enumerate(parts):
        verts = np.ascontiguousarray(verts, dtype=np.float32).reshape(-1, 3)
        if len(verts) < 4 or not np.isfinite(verts).all():
            raise ValueError(f"collision part {i} has {len(verts)} vertices or non-finite values")
        try:
            shape = physx.PhysxCollisionShapeConvexMesh(vertices=verts, scale=np.ones(3, np.float32),
                                                        material=material)
        except RuntimeError as err:  # PhysX failed to cook the hull (degenerate/flat part)
            raise ValueError(f"collision part {i} ({len(verts)} vertices) did not build: {err}") from err
        # PhysX "cooks" a flat, collinear or tiny part into a ~2 mm box without complaint.
        inflation = np.ptp(shape.get_vertices(), axis=0) - np.ptp(verts, axis=0)
        if tally is not None:
            tally["parts"] += 1
            tally["max_inflation_m"] = max(tally["max_inflation_m"], float(inflation.max()))
        if inflation.max() > max_inflation:
            raise ValueError(f"collision part {i} is degenerate (flat, collinear or < 1 mm): PhysX "
                             f"inflated it by {inflation.max() * 1000:.1f} mm")
        shape.set_collision_groups(collision_groups)
        shape.set_density(float(density))
        component.attach(shape)
        built += 1
    return built


def render_mesh_shape(mesh: trimesh.Trimesh, color, pose: sapien.Pose | None = None):
    """A SAPIEN render shape of ``mesh`` (m) with a plain colour ``(r, g, b)``."""
    verts = np.ascontiguousarray(mesh.vertices, dtype=np.float32)
    shape = sapien.render.RenderShapeTriangleMesh(
        verts, np.ascontiguousarray(mesh.faces, dtype=np.uint32),
        np.ascontiguousarray(mesh.vertex_normals, dtype=np.float32), np.zeros((len(verts), 2), np.float32),
        sapien.render.RenderMaterial(base_color=(*color, 1.0)))
    if pose is not None:
        shape.local_pose = pose
    return shape


def build_object_actor(scene, mesh: trimesh.Trimesh, parts: list[np.ndarray], name: str,
                       friction: float = 1.0, density: float = 500.0,
                       color: tuple[float, float, float] = (0.8, 0.45, 0.2), initial_z: float = 0.0,
                       scene_idxs: list[int] | None = None, tally: dict | None = None):
    """Build a dynamic actor: visual = ``mesh``, collision = ``parts``, all from memory.

    Args:
        scene: the ManiSkill scene.
        mesh: visual mesh (m).
        parts: convex collision parts, each ``(K, 3)`` (m), same frame as ``mesh``.
        name: unique actor name.
        friction: static and dynamic friction coefficient of the object.
        density: kg/m^3.
        color: RGB in [0, 1] of the visual.
        initial_z: z (m) of the actor frame at creation.
        scene_idxs: the parallel sub-scenes to build it in (``None``: all); one index per object when every
            sub-scene holds its own (then ``Actor.merge`` the actors, as ManiSkill's ``pick_single_ycb.py``).
        tally: a :func:`new_tally` record of the hulls built.

    Returns:
        The ManiSkill ``Actor``.

    Raises:
        ValueError: if ``parts`` is empty or not every part became a collision shape.
    """
    if len(parts) == 0:
        raise ValueError("an object needs at least one convex collision part")
    material = physx.PhysxMaterial(static_friction=friction, dynamic_friction=friction, restitution=0.0)
    builder = InMemoryActorBuilder(parts, material, density, tally)
    builder.set_scene(scene)
    if scene.can_render():
        builder._procedural_shapes.append(render_mesh_shape(mesh, color))
    builder.initial_pose = sapien.Pose(p=[0.0, 0.0, initial_z])
    if scene_idxs is not None:
        builder.set_scene_idxs(list(scene_idxs))
    actor = builder.build(name=name)
    built = len(actor._objs[0].find_component_by_type(physx.PhysxRigidDynamicComponent).collision_shapes)
    if built != len(parts) or builder.num_built_shapes != len(parts):
        raise ValueError(f"only {built} of {len(parts)} collision parts were built")
    return actor


def hemisphere_camera_configs(num: int, center: tuple[float, float, float], radius: float = 0.55,
                              elevations_deg: tuple[float, ...] = (50.0, 30.0), width: int = 360,
                              height: int = 240, fov: float = 0.75) -> list[CameraConfig]:
    """``num`` depth cameras on a hemisphere around ``center``, all looking at it.

    Azimuths are evenly spaced starting at 30 deg (off the robot's axis, which lies along -x);
    elevations alternate through ``elevations_deg``.

    Args:
        num: number of cameras (>= 1).
        center: the point every camera looks at (m, world frame).
        radius: distance (m) of each camera from ``center``.
        elevations_deg: elevations above the table plane, cycled over the cameras.
        width, height: image size in pixels (the paper uses 360 x 240).
        fov: vertical field of view (rad).
    """
    if num < 1:
        raise ValueError(f"num_cameras must be >= 1, got {num}")
    configs = []
    for i in range(num):
        az = np.deg2rad(30.0 + 360.0 * i / num)
        el = np.deg2rad(elevations_deg[i % len(elevations_deg)])
        eye = np.asarray(center) + radius * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az),
                                                      np.sin(el)])
        pose = sapien_utils.look_at(eye.tolist(), list(center))
        configs.append(CameraConfig(f"grt_depth_{i}", pose, width, height, fov, 0.05, 3.0,
                                    shader_pack="minimal"))
    return configs


def capture_segmented_cloud(scene, sensors: dict, segment_id: int, context_ids: tuple[int, ...] = ()
                            ) -> tuple[np.ndarray, np.ndarray] | tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Render every camera once and fuse the pixels of one actor into a world-frame point cloud.

    Args:
        scene: the ManiSkill scene (its render state is updated first).
        sensors: ``uid -> Camera`` (ManiSkill sensors) to capture.
        segment_id: the actor's ``per_scene_id`` (its id in the segmentation image).
        context_ids: ids of surrounding actors (e.g. the table) whose points are returned too.

    Returns:
        points: ``(P, 3)`` world-frame points (m) on the actor's visible surface.
        viewpoints: ``(P, 3)`` world position (m) of the camera that saw each point.
        context: ``(Q, 3)`` world-frame points of the ``context_ids`` actors (only when some are given).
    """
    scene.update_render(update_sensors=True, update_human_render_cameras=False)
    points, views, context = [], [], []
    for cam in sensors.values():
        cam.capture()
        obs = cam.get_obs(rgb=False, depth=False, position=True, segmentation=True)
        pos = np.asarray(obs["position"][0], np.float64).reshape(-1, 3) / 1000.0  # minimal shader: mm
        seg = np.asarray(obs["segmentation"][0]).reshape(-1)
        front = pos[:, 2] < 0  # OpenGL camera looks along -z
        model = np.asarray(cam.camera.get_model_matrix()[0], np.float64)  # cam2world (OpenGL)
        keep = (seg == segment_id) & front
        world = pos[keep] @ model[:3, :3].T + model[:3, 3]
        points.append(world)
        views.append(np.broadcast_to(model[:3, 3], world.shape))
        if context_ids:
            near = np.isin(seg, context_ids) & front
            context.append(pos[near] @ model[:3, :3].T + model[:3, 3])
    if context_ids:
        return np.concatenate(points), np.concatenate(views), np.concatenate(context)
    return np.concatenate(points), np.concatenate(views)
