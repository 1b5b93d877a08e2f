"""PyBullet physics of N differential-drive robots on a plane.

One :class:`PhysicsWorld` owns one PyBullet ``DIRECT`` client (never the global default
client), so several worlds can live in one process. Robots are the URDF of
:mod:`sim_server.urdf`; poses in and out are **axle-centre** poses ``(x_m, y_m, theta_rad)``,
the frame of :mod:`swarm.core.robot`; wheel commands are wheel **linear** speeds in m/s, as
:func:`swarm.core.robot.unicycle_to_wheels` produces them.

Construction choices (each measured; see ``docs`` / NOTES-measured): inertia from the URDF,
caster balls as collision shapes of the body link, wheels collide only with the ground
(collision filter groups), bodies collide with the ground and with each other (bumpers),
``VELOCITY_CONTROL`` on the wheel joints with a force limit, fixed physics rate and solver
iteration count, ``deterministicOverlappingPairs=1`` so the same inputs give bit-identical
results in any process.
"""

from __future__ import annotations

import contextlib
import math
import tempfile
from pathlib import Path
from types import TracebackType

import numpy as np
import pybullet as pb

from sim_server.urdf import packaged_urdf_path, render_urdf, write_urdf
from swarm.core.robot import RobotParams

GRAVITY_MPS2 = 9.81

# Collision filter groups (bit masks). Bullet lets two shapes touch when
# (group_a & mask_b) and (group_b & mask_a) are both non-zero.
GROUP_GROUND = 1
GROUP_WHEEL = 2
GROUP_BODY = 4
GROUP_OBSTACLE = 8
_MASK_GROUND = GROUP_WHEEL | GROUP_BODY
_MASK_WHEEL = GROUP_GROUND
_MASK_BODY = GROUP_GROUND | GROUP_BODY | GROUP_OBSTACLE
_MASK_OBSTACLE = GROUP_BODY

OBSTACLE_HEIGHT_M = 0.3
"""Height of the static obstacles (discs and walls stand on the ground; taller than any bumper)."""

WHEEL_TRACTION_LIMIT_N = 2.0
"""Default wheel motor limit, as the force at the tyre: torque limit = this x wheel radius.

Chosen so that the wheels never slip. Measured (default robot: 0.04 m wheels, 240 Hz,
10 iterations): with a torque limit of 0.1 N m or less a step command from rest to 0.5 m/s
turns the robot by ~1e-3 rad; from 0.12 N m up (0.5, 5 and 50 N m alike: friction is then
the limit) the wheels slip and Bullet's friction turns the robot by up to 0.05 rad, in a
direction that depends on its heading in the world. At 2 N per wheel (0.08 N m) the robot
accelerates at ~3 m/s^2 (0 to 0.5 m/s in ~0.2 s) and brakes from 0.5 m/s within ~4 cm.
"""

SETTLE_S = 0.1
"""Simulated time (at zero wheel speed) the robots rest on the ground at construction.

Measured with the default robot at 240 Hz / 10 solver iterations: the robot is placed at
its resting height and sinks ~1e-5 m into the ground (contact tolerance); while settling the
axle centre moves < 1e-4 m and the heading < 1e-4 rad (the same ~1 mm/s solver creep a robot
shows at rest with 10 iterations; 30 iterations cut it ~8x). ``time_s`` is 0 after settling:
settling is not counted.
"""


LARGE_SWARM_PHYSICS_HZ = 40.0
LARGE_SWARM_SOLVER_ITERATIONS = 30
"""Physics settings for large swarms (``sim.physics_hz: 40``, ``sim.solver_iterations: 30``; the
runtime benchmark uses them from N = 100 on). Measured, 100 robots on one core (CPU per 0.05 s
control period): 240 Hz / 10 iterations 43 ms, 120 / 10 18 ms, 60 / 10 9.4 ms, 40 / 30 9.3 ms,
20 / 50 5.2 ms. Against the unicycle model (the 10 s schedule of ``tests/test_physics.py``, limit
3 cm and 30 mrad): 240 / 10 0.6-1.0 cm and 6-10 mrad, 120 / 10 0.8-1.2 cm and 9-17 mrad,
60 / 10 2.2-2.5 cm and 29-37 mrad (fails), 40 / 30 0.1-0.3 cm and 2-6 mrad (and rest creep 0.6-0.8
mm/s, less than 240 / 10), 20 / 50 passes the schedule but lets bumpers overlap 1 cm in a pile-up
(fails). Two substeps of 25 ms with 30 iterations: the cost of 60 Hz, the accuracy of 240 Hz."""


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of (..., 4) quaternions stored as (x, y, z, w), PyBullet's order."""
    ax, ay, az, aw = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bx, by, bz, bw = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ],
        axis=-1,
    )


def _yaw(q: np.ndarray) -> np.ndarray:
    """Heading of the body x axis projected on the ground plane, in [-pi, pi]."""
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


class PhysicsWorld:
    """N BubbleRob-like robots in a PyBullet ``DIRECT`` world.

    Args:
        robot: robot parameters (wheel radius, half axle, bumper radius).
        initial_poses: ``(N, 3)`` axle-centre poses ``(x_m, y_m, theta_rad)``.
        physics_hz: physics rate (fixed time step ``1 / physics_hz``).
        solver_iterations: Bullet's ``numSolverIterations``.
        wheel_force_limit_nm: maximum torque of each wheel motor in N m (VELOCITY_CONTROL
            ``force``); ``None``: :data:`WHEEL_TRACTION_LIMIT_N` x wheel radius (0.08 N m for
            the default robot). Above ~0.11 N m (default robot) the wheels slip on a step
            command and the robot gets a spurious heading kick.
        obstacles: static capsules ``(start, end, radius)`` (``swarm.core.obstacles``): a vertical
            cylinder for a disc, a box with a cylinder at each end for a wall, ``OBSTACLE_HEIGHT_M``
            tall, touched by the robots' bodies (not their wheels).
        count_contacts: after every physics substep, read PyBullet's contact points and keep the
            robot-robot and robot-obstacle pairs touching (:meth:`take_contacts`).

    Use as a context manager, or call :meth:`close`.

    Known limits (default robot, 240 Hz, 10 iterations; see tests/test_physics.py): the
    unconverged solver leaves a forward creep of ~0.9 mm/s and a yaw drift of < 0.6 mrad/s,
    also at rest (30 iterations: ~8x less); the actuators' finite acceleration (see
    :data:`WHEEL_TRACTION_LIMIT_N`) makes the robot lag the unicycle model after each
    command change (~1 cm and ~0.01 rad over a 10 s, 2.6 m drive at 20 Hz control).
    """

    def __init__(
        self,
        robot: RobotParams,
        initial_poses: np.ndarray,
        physics_hz: float = 240.0,
        solver_iterations: int = 10,
        wheel_force_limit_nm: float | None = None,
        obstacles: tuple[tuple[tuple[float, float], tuple[float, float], float], ...] = (),
        count_contacts: bool = False,
    ) -> None:
        poses = np.asarray(initial_poses, dtype=np.float64)
        if poses.ndim != 2 or poses.shape[1] != 3:
            raise ValueError(f"initial_poses must have shape (N, 3), got {poses.shape}")
        if not np.all(np.isfinite(poses)):
            raise ValueError("initial_poses must be finite")
        if physics_hz <= 0:
            raise ValueError(f"physics_hz must be positive, got {physics_hz}")
        if solver_iterations < 1:
            raise ValueError(f"solver_iterations must be >= 1, got {solver_iterations}")
        if wheel_force_limit_nm is None:
            wheel_force_limit_nm = WHEEL_TRACTION_LIMIT_N * robot.wheel_radius_m
        if wheel_force_limit_nm <= 0:
            raise ValueError(f"wheel_force_limit_nm must be positive, got {wheel_force_limit_nm}")

        self.robot = robot
        self.physics_hz = float(physics_hz)
        self.solver_iterations = int(solver_iterations)
        self.wheel_force_limit_nm = float(wheel_force_limit_nm)
        self._n = poses.shape[0]
        self._steps = 0
        self._client: int | None = pb.connect(pb.DIRECT)
        cid = self._client
        self._cid = cid
        try:
            pb.resetSimulation(physicsClientId=cid)
            pb.setGravity(0.0, 0.0, -GRAVITY_MPS2, physicsClientId=cid)
            pb.setPhysicsEngineParameter(
                fixedTimeStep=1.0 / self.physics_hz,
                numSolverIterations=self.solver_iterations,
                numSubSteps=0,
                deterministicOverlappingPairs=1,
                physicsClientId=cid,
            )
            self._plane = self._make_ground(cid)
            self._bodies = self._load_robots(robot, poses, cid)
            self._robot_of_body = {body: i for i, body in enumerate(self._bodies)}
            self._obstacle_of_body: dict[int, int] = {}
            for index, capsule in enumerate(obstacles):
                for body in self._make_obstacle(capsule, cid):
                    self._obstacle_of_body[body] = index
            self.count_contacts = bool(count_contacts)
            self._robots_touching: set[tuple[int, int]] = set()  # since the last take_contacts
            self._walls_touching: set[tuple[int, int]] = set()
            self._joints = [0, 1]  # left, right: the URDF's joint order
            self._forces = [self.wheel_force_limit_nm, self.wheel_force_limit_nm]
            # Body-frame offset of the base link's centre of mass (getBasePositionAndOrientation
            # reports that frame, not the URDF link frame).
            info = pb.getDynamicsInfo(self._bodies[0], -1, physicsClientId=cid) if self._n else None
            com_pos = info[3] if info else (0.0, 0.0, 0.0)
            com_orn = info[4] if info else (0.0, 0.0, 0.0, 1.0)
            self._com_pos_local = np.asarray(com_pos, dtype=np.float64)
            inv_com_orn = np.array([-com_orn[0], -com_orn[1], -com_orn[2], com_orn[3]], dtype=np.float64)
            self._inv_com_orn = inv_com_orn
            self._com_orn_identity = bool(np.allclose(inv_com_orn, [0.0, 0.0, 0.0, 1.0], atol=1e-12))
            self._wheels = np.zeros((self._n, 2), dtype=np.float64)
            self.set_wheel_speeds(self._wheels)
            for _ in range(round(SETTLE_S * self.physics_hz)):
                pb.stepSimulation(physicsClientId=cid)
        except BaseException:
            self.close()
            raise

    # ----------------------------------------------------------------- construction
    @staticmethod
    def _make_ground(cid: int) -> int:
        shape = pb.createCollisionShape(pb.GEOM_PLANE, physicsClientId=cid)
        plane = pb.createMultiBody(0.0, shape, -1, [0.0, 0.0, 0.0], physicsClientId=cid)
        pb.changeDynamics(plane, -1, lateralFriction=1.0, physicsClientId=cid)
        pb.setCollisionFilterGroupMask(plane, -1, GROUP_GROUND, _MASK_GROUND, physicsClientId=cid)
        return plane

    @staticmethod
    def _make_obstacle(capsule, cid: int) -> list[int]:
        """The static bodies of one capsule: a cylinder at each end (one for a disc) and, for a wall, a
        box between them, all standing on the ground."""
        (x0, y0), (x1, y1), radius = capsule
        half_height = 0.5 * OBSTACLE_HEIGHT_M
        length = math.hypot(x1 - x0, y1 - y0)
        ends = [(x0, y0)] if length == 0 else [(x0, y0), (x1, y1)]
        bodies = []
        for x, y in ends:
            shape = pb.createCollisionShape(
                pb.GEOM_CYLINDER, radius=radius, height=OBSTACLE_HEIGHT_M, physicsClientId=cid
            )
            bodies.append(pb.createMultiBody(0.0, shape, -1, [x, y, half_height], physicsClientId=cid))
        if length > 0:
            yaw = math.atan2(y1 - y0, x1 - x0)
            shape = pb.createCollisionShape(
                pb.GEOM_BOX, halfExtents=[0.5 * length, radius, half_height], physicsClientId=cid
            )
            centre = [0.5 * (x0 + x1), 0.5 * (y0 + y1), half_height]
            turn = [0.0, 0.0, math.sin(0.5 * yaw), math.cos(0.5 * yaw)]
            bodies.append(pb.createMultiBody(0.0, shape, -1, centre, turn, physicsClientId=cid))
        for body in bodies:
            pb.setCollisionFilterGroupMask(body, -1, GROUP_OBSTACLE, _MASK_OBSTACLE, physicsClientId=cid)
        return bodies

    @staticmethod
    def _load_robots(robot: RobotParams, poses: np.ndarray, cid: int) -> list[int]:
        flags = pb.URDF_USE_INERTIA_FROM_FILE | pb.URDF_ENABLE_CACHED_GRAPHICS_SHAPES
        bodies: list[int] = []
        with tempfile.TemporaryDirectory(prefix="bubblerob-") as tmp:
            packaged = packaged_urdf_path()
            text = render_urdf(robot)
            if packaged.is_file() and packaged.read_text(encoding="utf-8") == text:
                path = packaged
            else:
                path = write_urdf(Path(tmp) / "bubblerob.urdf", robot)
            for x, y, theta in poses:
                # loadURDF places the URDF link frame (the axle centre), resting on the ground.
                body = pb.loadURDF(
                    str(path),
                    basePosition=[float(x), float(y), robot.wheel_radius_m],
                    baseOrientation=[0.0, 0.0, math.sin(0.5 * theta), math.cos(0.5 * theta)],
                    flags=flags,
                    physicsClientId=cid,
                )
                pb.setCollisionFilterGroupMask(body, -1, GROUP_BODY, _MASK_BODY, physicsClientId=cid)
                for link in (0, 1):
                    pb.setCollisionFilterGroupMask(body, link, GROUP_WHEEL, _MASK_WHEEL, physicsClientId=cid)
                bodies.append(body)
        return bodies

    # ----------------------------------------------------------------- API
    @property
    def num_robots(self) -> int:
        return self._n

    @property
    def time_s(self) -> float:
        """Simulated time since construction (after settling): substeps / physics_hz."""
        return self._steps / self.physics_hz

    @property
    def client_id(self) -> int:
        """The PyBullet client id of this world (for inspection; do not disconnect it)."""
        if self._client is None:
            raise RuntimeError("PhysicsWorld is closed")
        return self._client

    @property
    def body_ids(self) -> tuple[int, ...]:
        """PyBullet body ids of the robots, in robot order."""
        return tuple(self._bodies)

    def set_wheel_speeds(self, wheels: np.ndarray) -> None:
        """Command wheel linear speeds ``(N, 2)`` as (left, right) in m/s; they hold until changed.

        Converted to joint angular speeds ``v / wheel_radius`` and applied with
        ``VELOCITY_CONTROL`` and the world's force limit. No saturation here: the caller
        (agent / controller) saturates with :func:`swarm.core.robot.saturate_wheels`.
        """
        w = np.asarray(wheels, dtype=np.float64)
        if w.shape != (self._n, 2):
            raise ValueError(f"wheels must have shape ({self._n}, 2), got {w.shape}")
        if not np.all(np.isfinite(w)):
            raise ValueError("wheel speeds must be finite")
        self._wheels[:] = w
        targets = (w / self.robot.wheel_radius_m).tolist()
        cid, joints, forces, mode = self._cid, self._joints, self._forces, pb.VELOCITY_CONTROL
        for body, target in zip(self._bodies, targets, strict=True):
            pb.setJointMotorControlArray(
                body, joints, mode, targetVelocities=target, forces=forces, physicsClientId=cid
            )

    def stop_robot(self, i: int) -> None:
        """Command zero wheel speed to robot ``i`` (the motors brake it, friction-limited)."""
        if not 0 <= i < self._n:
            raise IndexError(f"robot index {i} out of range for {self._n} robots")
        self._wheels[i] = 0.0
        pb.setJointMotorControlArray(
            self._bodies[i],
            self._joints,
            pb.VELOCITY_CONTROL,
            targetVelocities=[0.0, 0.0],
            forces=self._forces,
            physicsClientId=self._cid,
        )

    @property
    def wheel_speeds(self) -> np.ndarray:
        """Currently commanded wheel linear speeds ``(N, 2)`` in m/s (a copy)."""
        return self._wheels.copy()

    def step(self, duration_s: float) -> float:
        """Advance the physics by ``round(duration_s * physics_hz)`` fixed substeps.

        The duration is rounded to a whole number of substeps (a 0.05 s control period at
        240 Hz is exactly 12 substeps; choose periods that are multiples of ``1 / physics_hz``).
        Returns the simulated time actually advanced, in seconds.
        """
        if duration_s < 0:
            raise ValueError(f"duration_s must be >= 0, got {duration_s}")
        n = round(duration_s * self.physics_hz)
        cid = self._cid
        step = pb.stepSimulation
        for _ in range(n):
            step(physicsClientId=cid)
            if self.count_contacts:
                self._note_contacts()
        self._steps += n
        return n / self.physics_hz

    def _note_contacts(self) -> None:
        """Add the robot-robot and robot-obstacle pairs touching now (a contact point at distance <= 0:
        Bullet's manifolds also keep points a little apart, which are no contact)."""
        robot_of, obstacle_of = self._robot_of_body, self._obstacle_of_body
        robots, walls = self._robots_touching, self._walls_touching
        for point in pb.getContactPoints(physicsClientId=self._cid):
            if point[8] > 0.0:
                continue
            a, b = point[1], point[2]
            if a in robot_of and b in robot_of:
                i, j = sorted((robot_of[a], robot_of[b]))
                robots.add((i, j))
            elif a in robot_of and b in obstacle_of:
                walls.add((robot_of[a], obstacle_of[b]))
            elif b in robot_of and a in obstacle_of:
                walls.add((robot_of[b], obstacle_of[a]))

    def take_contacts(self) -> tuple[set[tuple[int, int]], set[tuple[int, int]]]:
        """The pairs that touched at any substep since the last call (``count_contacts``): robot pairs
        ``(i, j)`` with ``i < j``, and ``(robot, obstacle)`` pairs; then forgets them."""
        robots, walls = self._robots_touching, self._walls_touching
        self._robots_touching, self._walls_touching = set(), set()
        return robots, walls

    def _read_base_states(self) -> np.ndarray:
        """(N, 7) centre-of-mass position and orientation (x, y, z, qx, qy, qz, qw) per robot."""
        cid = self._cid
        get = pb.getBasePositionAndOrientation
        states = [pos + orn for pos, orn in [get(body, physicsClientId=cid) for body in self._bodies]]
        return np.array(states, dtype=np.float64).reshape(self._n, 7)

    def _link_frames(self) -> tuple[np.ndarray, np.ndarray]:
        """Axle-centre (URDF link) frames: positions (N, 3) and orientations (N, 4) (x, y, z, w)."""
        raw = self._read_base_states()
        orn = raw[:, 3:] if self._com_orn_identity else _quat_mul(raw[:, 3:], self._inv_com_orn)
        x, y, z, w = orn.T
        cx, cy, cz = self._com_pos_local
        # link origin = COM position - R(orn) @ com_offset, rotation matrix written out (cheap for small N)
        pos = raw[:, :3].copy()
        pos[:, 0] -= (1 - 2 * (y * y + z * z)) * cx + 2 * (x * y - z * w) * cy + 2 * (x * z + y * w) * cz
        pos[:, 1] -= 2 * (x * y + z * w) * cx + (1 - 2 * (x * x + z * z)) * cy + 2 * (y * z - x * w) * cz
        pos[:, 2] -= 2 * (x * z - y * w) * cx + 2 * (y * z + x * w) * cy + (1 - 2 * (x * x + y * y)) * cz
        return pos, orn

    def poses(self) -> np.ndarray:
        """Axle-centre poses ``(N, 3)``: ``(x_m, y_m, theta_rad)``, theta the yaw in [-pi, pi]."""
        pos, orn = self._link_frames()
        out = np.empty((self._n, 3), dtype=np.float64)
        out[:, :2] = pos[:, :2]
        out[:, 2] = _yaw(orn)
        return out

    def tilt_rad(self) -> np.ndarray:
        """Angle ``(N,)`` between each robot's up axis and the world vertical (0 = upright)."""
        _, orn = self._link_frames()
        x, y = orn[:, 0], orn[:, 1]
        cos_tilt = 1.0 - 2.0 * (x * x + y * y)  # z component of the rotated body z axis
        return np.arccos(np.clip(cos_tilt, -1.0, 1.0))

    def axle_heights(self) -> np.ndarray:
        """Height ``(N,)`` of each axle centre above the ground in metres (wheel radius at rest)."""
        pos, _ = self._link_frames()
        return pos[:, 2].copy()

    def close(self) -> None:
        """Disconnect the PyBullet client. Idempotent."""
        client, self._client = getattr(self, "_client", None), None
        if client is not None:
            with contextlib.suppress(pb.error):
                pb.disconnect(physicsClientId=client)

    def __enter__(self) -> PhysicsWorld:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
