"""The only module that imports dartpy: DART world <-> the stepper's plain data.

What DART keeps doing: mass matrices, Coriolis and gravity forces, external and joint forces,
position integration (`integratePositions`), world time. What this module adds:

* ``attach(body_node, shape, friction=...)`` stores an implicit shape on a body. The shape is
  written, as JSON, into the name of a visual-only ShapeNode (prefix ``implicit_contact:``), so the
  world carries it itself: no global registry, and ``World.clone()`` keeps it.
* DART primitive ShapeNodes that have a collision aspect (what DART's own detector would collide)
  are mapped to implicit surfaces: Sphere, Ellipsoid, Cylinder (a capped cylinder, an intersection
  of three functions), Box (an intersection of six half-spaces), Plane (a half-space). On a
  PlanarJoint body a z-axis cylinder or a sphere becomes a disc and a box a rectangle, so the
  paper's planar scenes can use DART primitives.
* Body kinds: a single-body skeleton with a FreeJoint root (6 dofs) or a PlanarJoint root in the
  XY plane (3 dofs [x, y, theta]) keeps the fast kinds FREE / PLANAR; fixed bodies (WeldJoint
  roots, immobile skeletons, and bodies of a mobile skeleton that no dof moves) are FIXED; every
  other body of a mobile skeleton is ARTICULATED (3D shapes): multi-body skeletons and other roots,
  with Revolute, Prismatic, Screw, Universal, Ball, Euler, Translational, TranslationalJoint2D,
  Planar, Free and Weld joints. An ARTICULATED body carries DART's world Jacobian of its origin at
  l; all bodies of a skeleton share its velocity unknowns (formulation.BodyKinematics). Refused at
  construction, with a sentence each: enforced position limits on Ball and Free joints (their
  rotation is not q + h v), actuators other than FORCE / PASSIVE (servo, velocity,
  acceleration, locked and mimic joints are DART constraints). A MeshShape is its convex hull,
  simplified to few planes with a bounded outward error (hulls.py). Coulomb joint friction
  (joint.setCoulombFriction) and enforced position limits (joint.setLimitEnforcement) are read
  when the stepper is built and become joint rows of the step's MCP (joint_rows.py). Pairs of two bodies of the same skeleton are not candidates (no self-collision, DART's
  default).
* Generalized force at l: tau (commands, already clamped by DART to the force limits) + tau_ext -
  (Coriolis + gravity), and joint springs and dampers as DART applies them: DART treats them
  implicitly (GenericJoint: the spring acts at q + h v+ and the damper at v+, i.e. h D + h^2 K is
  added to the articulated inertia), and so does this module: it returns M + h D + h^2 K as the
  mass matrix and -K (q - q_rest + h v) - D v in the force, so M (v+ - v) = h force + J^T P is
  DART's own semi-implicit step with the contact impulses added (tested: a damped pendulum in free
  flight matches world.step() to 1e-12). K, D and q_rest are read when the stepper is built.

The FreeJoint velocity convention changed between dartpy releases; this module measures it at
start-up (``check_free_joint_convention``) and refuses a convention it was not written for.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import functools
import json
import math
import os

import dartpy as dart
import numpy as np

from . import hulls
from . import shapes as shp
from . import step_kernels
from .params import Compliance, Friction

SHAPE_NODE_PREFIX = "implicit_contact:"
DEFAULT_DART_MU = 1.0  # DART's DynamicsAspect default friction coefficient

FREE, PLANAR, FIXED = "free", "planar", "fixed"
ARTICULATED = "articulated"

# joints whose motion DART integrates with integratePositions and describes by its Jacobian
SUPPORTED_JOINTS = ("RevoluteJoint", "PrismaticJoint", "ScrewJoint", "UniversalJoint", "BallJoint",
                    "EulerJoint", "TranslationalJoint", "TranslationalJoint2D", "PlanarJoint",
                    "FreeJoint", "WeldJoint")


# --------------------------------------------------------------------------------------------
# attach
# --------------------------------------------------------------------------------------------
def attach(body_node, shape, friction: Friction | None = None, compliance=None, name: str | None = None):
    """Give ``body_node`` the implicit surface ``shape`` (body frame) for the implicit stepper.

    friction: the body's ``ic.Friction`` (default mu = 0); a pair uses the smaller mu of its two
    bodies unless ``stepper.set_pair_friction`` overrides it. compliance: an ``ic.Compliance`` for a
    quasi-rigid body (see the quasi-rigid issue); None for rigid. Returns the DART ShapeNode that
    stores the shape (visual only: DART's own detector ignores it).
    """
    if not isinstance(shape, (shp.ConvexFunction, shp.Intersection, shp.Union)):
        raise ValueError(f"attach() needs an implicit_contact.shapes shape, got {type(shape).__name__}")
    friction = Friction() if friction is None else friction
    if not isinstance(friction, Friction):
        raise ValueError(f"friction must be an ic.Friction, got {type(friction).__name__}")
    if compliance is not None and not isinstance(compliance, Compliance):
        raise ValueError(f"compliance must be an ic.Compliance or None, got {type(compliance).__name__}")
    record = {"shape": shape.to_dict(), "friction": friction.to_dict()}
    if compliance is not None:
        record["compliance"] = compliance.to_dict()
    if name is not None:
        record["name"] = str(name)
    node = body_node.createShapeNode(_visual_proxy(shape))
    node.setName(SHAPE_NODE_PREFIX + json.dumps(record, separators=(",", ":")))
    node.createVisualAspect()
    return node


def _visual_proxy(shape):
    """A DART shape for viewers only: the implicit body's bounding box (or a sphere)."""
    if isinstance(shape, shp.Sphere):
        return dart.dynamics.SphereShape(float(shape.radius))
    lo, hi = shape.aabb(np.eye(shape.dim), np.zeros(shape.dim))
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    size = np.where(np.isfinite(hi - lo), hi - lo, 10.0)
    if shape.dim == 2:
        size = np.append(size, 0.1)
    return dart.dynamics.BoxShape(np.maximum(size, 1e-3))


def _parse_record(node_name: str) -> dict:
    text = node_name[len(SHAPE_NODE_PREFIX):]
    # DART makes names unique by appending "(k)": keep the JSON object only.
    text = text[: text.rfind("}") + 1]
    return json.loads(text)


# --------------------------------------------------------------------------------------------
# DART primitives -> implicit surfaces
# --------------------------------------------------------------------------------------------
def _placement(node):
    T = node.getRelativeTransform().matrix()
    return T[:3, :3].copy(), T[:3, 3].copy()


def implicit_from_dart_shape(dart_shape, rotation, translation, planar: bool):
    """Map a DART primitive (placed by ``rotation``, ``translation`` in its body) to a shape.

    planar: the body moves in the XY plane; the result is then a 2D section, which needs the
    primitive's axis along z (cylinder, box) or any orientation (sphere).
    """
    kind = dart_shape.getType()
    R, c = np.asarray(rotation, float), np.asarray(translation, float)
    if planar:
        if not np.allclose(R[2], [0.0, 0.0, 1.0], atol=1e-12):
            raise ValueError(f"a {kind} on a planar body must keep its z axis along the plane normal")
        angle = math.atan2(R[1, 0], R[0, 0])
        if kind == "SphereShape":
            return shp.Disc(dart_shape.getRadius(), center=c[:2])
        if kind == "CylinderShape":
            return shp.Disc(dart_shape.getRadius(), center=c[:2])
        if kind == "EllipsoidShape":
            d = np.asarray(dart_shape.getDiameters(), float)
            return shp.Ellipse(d[:2] / 2.0, center=c[:2], rotation=angle)
        if kind == "BoxShape":
            size = np.asarray(dart_shape.getSize(), float)
            return _placed_rectangle(size[:2] / 2.0, c[:2], angle)
        raise ValueError(f"{kind} is not supported on a planar body: supported are SphereShape, "
                         "CylinderShape, EllipsoidShape and BoxShape, or attach a 2D implicit shape "
                         "with ic.attach(body_node, ic.shapes.Disc(...)).")
    if kind == "SphereShape":
        return shp.Sphere(dart_shape.getRadius(), center=c, rotation=R)
    if kind == "EllipsoidShape":
        return shp.Ellipsoid(np.asarray(dart_shape.getDiameters(), float) / 2.0, center=c, rotation=R)
    if kind == "CylinderShape":
        return _placed_intersection(
            shp.Intersection.capped_cylinder(dart_shape.getRadius(), dart_shape.getHeight() / 2.0), R, c)
    if kind == "BoxShape":
        return _placed_intersection(
            shp.Intersection.box(np.asarray(dart_shape.getSize(), float) / 2.0), R, c)
    if kind == "PlaneShape":
        n = R @ np.asarray(dart_shape.getNormal(), float)
        return shp.HalfSpace(n, float(dart_shape.getOffset()) + float(n @ c))
    if kind == "MeshShape":
        # its convex hull (MuJoCo's convention), simplified to few planes (hulls.py)
        path = dart_shape.getMeshPath()
        if not path or not os.path.exists(path):
            raise ValueError(f"a MeshShape's file '{path}' cannot be read (its URI: "
                             f"'{dart_shape.getMeshUri()}'): the stepper takes a mesh's hull from its file's "
                             "vertices; load it from a file, or attach an implicit surface with "
                             "ic.attach(body_node, shape).")
        hull = hulls.mesh_hull(path, dart_shape.getScale())
        if not hull.error <= hull.tolerance:
            raise ValueError(f"the convex hull of mesh '{path}' cannot be simplified to within "
                             f"{hull.tolerance:.3g} m in {len(hull.normals)} planes (error {hull.error:.3g} m); "
                             "attach an implicit surface with ic.attach(body_node, shape).")
        return shp.Intersection.polytope(hull.normals, hull.offsets, center=c, rotation=R)
    raise ValueError(f"{kind} is not supported by the implicit stepper: supported DART shapes are "
                     "SphereShape, EllipsoidShape, CylinderShape, BoxShape, PlaneShape and MeshShape (its "
                     "convex hull); for other shapes attach an implicit surface with "
                     "ic.attach(body_node, shape).")


def _placed_intersection(inter, R, c):
    """Re-place every function of an intersection by (R, c) inside the body."""
    parts = [shp.shape_from_dict(_compose_placement(f.to_dict(), R, c)) for f in inter.functions]
    return shp.Intersection(parts)


def _placed_rectangle(half, c, angle):
    ca, sa = math.cos(angle), math.sin(angle)
    Rz = np.array([[ca, -sa], [sa, ca]])
    normals = [Rz @ np.array(v) for v in ((1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0))]
    offsets = [half[0], half[0], half[1], half[1]]
    return shp.Intersection([shp.HalfPlane(n, o + float(n @ c)) for n, o in zip(normals, offsets)])


def _compose_placement(d: dict, R, c) -> dict:
    """Compose a 3D shape dict's own placement (R0, c0) with a body placement (R, c)."""
    d = dict(d)
    R0 = np.asarray(d["rotation"] if d.get("rotation") is not None else np.eye(3), float)
    c0 = np.asarray(d["center"] if d.get("center") is not None else np.zeros(3), float)
    d["rotation"] = (R @ R0).tolist()
    d["center"] = (R @ c0 + c).tolist()
    return d


# --------------------------------------------------------------------------------------------
# Scene description
# --------------------------------------------------------------------------------------------
@dataclass
class ContactShape:
    """One implicit shape on one body, as the stepper sees it."""
    shape: object              # ConvexFunction | Intersection | Union, body frame
    friction: Friction
    compliance: object = None
    label: str = ""


@dataclass
class BodyRecord:
    """A body that carries contact shapes."""
    index: int
    body_node: object
    skeleton: object
    skeleton_index: int        # index into Scene.skeletons, or -1 for a fixed body
    kind: str                  # FREE | PLANAR | FIXED | ARTICULATED
    dim: int                   # 3, or 2 for planar bodies
    shapes: list = field(default_factory=list)
    name: str = ""
    world_skeleton: int = -1   # index of its skeleton in the world (pairs within one are skipped)


@dataclass
class SkeletonRecord:
    skeleton: object
    kind: str
    ndof: int
    body_index: int            # the BodyRecord of its first body with shapes, or -1 if none
    body_indices: list = field(default_factory=list)   # all its mobile bodies with shapes
    spring_damper: tuple | None = None   # per dof (K, D, q_rest), read when the stepper is built
    coulomb: np.ndarray | None = None    # per dof Coulomb joint friction [N, N m], read then too
    limits: tuple | None = None          # (dofs, lower, upper) of enforced position limits, read then
    mimic: tuple = ()                    # (follower dof, leader dof, multiplier, offset) per mimic joint


@dataclass
class Scene:
    skeletons: list            # mobile skeletons stepped by the stepper
    bodies: list               # bodies with contact shapes (mobile and fixed)


def _joint_kind(skel, mimic=frozenset()) -> str:
    """FIXED (immobile), FREE / PLANAR (a single body on a Free / XY-Planar root with identity
    offsets: the fast path) or ARTICULATED (everything else; its joints checked by _check_joints)."""
    if skel.getNumDofs() == 0 or not skel.isMobile():
        return FIXED
    _check_joints(skel, mimic)
    if skel.getNumBodyNodes() != 1:
        return ARTICULATED
    joint = skel.getJoint(0)
    jtype = joint.getType()
    offsets_identity = (np.allclose(joint.getTransformFromParentBodyNode().matrix(), np.eye(4))
                        and np.allclose(joint.getTransformFromChildBodyNode().matrix(), np.eye(4)))
    if jtype == "FreeJoint" and offsets_identity:
        return FREE
    if jtype == "PlanarJoint":
        xy = (np.allclose(joint.getRotationalAxis(), [0.0, 0.0, 1.0])
              and np.allclose(joint.getTranslationalAxis1(), [1.0, 0.0, 0.0])
              and np.allclose(joint.getTranslationalAxis2(), [0.0, 1.0, 0.0]))
        if offsets_identity and xy:
            return PLANAR
    return ARTICULATED


_PLAIN_ACTUATORS = ("FORCE", "PASSIVE")
_EXP_MAP_JOINTS = ("BallJoint", "FreeJoint")    # their rotation integrates on SO(3)


def _check_joints(skel, mimic=frozenset()) -> None:
    """Refuse what DART handles as constraints (the implicit stepper replaces DART's constraint
    solver, so it would silently drop them) and joint types it was not written for; mimic: the
    names of the joints whose mimic relation the stepper was given."""
    for j in range(skel.getNumJoints()):
        joint = skel.getJoint(j)
        jtype = joint.getType()
        where = f"joint '{joint.getName()}' ({jtype}) of skeleton '{skel.getName()}'"
        if jtype not in SUPPORTED_JOINTS:
            raise ValueError(f"{where} is not supported by the implicit stepper: supported joints are "
                             + ", ".join(SUPPORTED_JOINTS) + ".")
        n = joint.getNumDofs()
        if n == 0:
            continue
        if joint.areLimitsEnforced() and jtype in _EXP_MAP_JOINTS:
            raise ValueError(f"{where} enforces position limits: the implicit stepper holds limits on "
                             "coordinates that integrate as q + h v, which a " + jtype + "'s rotation does "
                             "not; disable them (joint.setLimitEnforcement(False)) or model the stop "
                             "as a contact shape.")
        for i in range(n):
            act = joint.getActuatorType(i) if _actuator_per_dof(joint) else joint.getActuatorType()
            if act.name == "MIMIC" and joint.getName() not in mimic:
                raise ValueError(f"{where} is a mimic joint: dartpy does not expose its relation, so give it "
                                 "to the stepper, ImplicitContactStepper(world, mimic={follower: (leader, "
                                 "multiplier, offset)}); for a URDF, mimic=ic.urdf_mimic_joints(urdf_text).")
            if act.name not in _PLAIN_ACTUATORS and act.name != "MIMIC":
                raise ValueError(f"{where} has actuator type {act.name}: the implicit stepper supports "
                                 "FORCE and PASSIVE joints (DART enforces servo, velocity, "
                                 "acceleration, locked and mimic joints as constraints); command "
                                 "joint forces instead.")
            friction = joint.getCoulombFriction(i)
            if not (math.isfinite(friction) and friction >= 0.0):
                raise ValueError(f"{where} has Coulomb joint friction {friction} on dof {i}: it must be a "
                                 "finite force >= 0.")


def _actuator_per_dof(joint) -> bool:
    try:
        joint.getActuatorType(0)
        return True
    except TypeError:
        return False


def scan_world(world, mimic=None) -> Scene:
    """Find every body with contact shapes; validate joints, masses and shape dimensions; mimic:
    {follower joint name: (leader joint name, multiplier, offset)} (see _mimic_rows)."""
    mimic = dict(mimic or {})
    skeletons, bodies = [], []
    for s in range(world.getNumSkeletons()):
        skel = world.getSkeleton(s)
        sk_kind = _joint_kind(skel, frozenset(mimic))
        sk_index = -1
        if sk_kind != FIXED:
            sk_index = len(skeletons)
            skeletons.append(SkeletonRecord(skel, sk_kind, skel.getNumDofs(), -1,
                                            spring_damper=_spring_damper(skel), coulomb=_coulomb(skel),
                                            limits=_limits(skel), mimic=_mimic_rows(skel, mimic)))
            if sk_kind == ARTICULATED:
                _check_mass_matrix(skel)
        for b in range(skel.getNumBodyNodes()):
            node = skel.getBodyNode(b)
            kind = sk_kind
            if kind == ARTICULATED and node.getNumDependentGenCoords() == 0:
                kind = FIXED           # welded to the world: no dof moves it
            found = _shapes_of(node, planar=(kind == PLANAR))
            if not found:
                continue
            dims = {cs.shape.dim for cs in found}
            want = 2 if kind == PLANAR else None
            if kind == PLANAR and dims != {2}:
                raise ValueError(f"body '{node.getName()}' is on a PlanarJoint and needs 2D shapes "
                                 "(Disc, Ellipse, Superellipse, HalfPlane, rectangles).")
            if kind == FREE and dims != {3}:
                raise ValueError(f"body '{node.getName()}' is on a FreeJoint and needs 3D shapes; 2D "
                                 "shapes need a PlanarJoint body.")
            if kind == ARTICULATED and dims != {3}:
                raise ValueError(f"body '{node.getName()}' belongs to an articulated skeleton and needs "
                                 "3D shapes; 2D shapes need a single-body PlanarJoint skeleton in the "
                                 "XY plane.")
            if kind == FIXED and len(dims) != 1:
                raise ValueError(f"fixed body '{node.getName()}' mixes 2D and 3D shapes; give it one kind.")
            dim = want or dims.pop()
            if kind in (FREE, PLANAR):
                _check_mass(node)
            rec = BodyRecord(len(bodies), node, skel, sk_index if kind != FIXED else -1, kind, dim, found,
                             name=f"{skel.getName()}/{node.getName()}", world_skeleton=s)
            bodies.append(rec)
            if kind != FIXED:
                if skeletons[sk_index].body_index < 0:
                    skeletons[sk_index].body_index = rec.index
                skeletons[sk_index].body_indices.append(rec.index)
    known = {rec.skeleton.getJoint(j).getName() for rec in skeletons for j in range(rec.skeleton.getNumJoints())}
    missing = sorted(set(mimic) - known)
    if missing:
        raise ValueError(f"mimic joints {missing} are not joints of a mobile skeleton of this world.")
    return Scene(skeletons, bodies)


def _check_mass_matrix(skel):
    M = np.asarray(skel.getMassMatrix(), float)
    ok = bool(np.all(np.isfinite(M)))
    if ok:
        try:
            np.linalg.cholesky(0.5 * (M + M.T))
        except np.linalg.LinAlgError:
            ok = False
    if not ok:
        raise ValueError(f"skeleton '{skel.getName()}' has a mass matrix that is not positive definite: "
                         "give every body a positive mass and inertia.")


def _check_mass(node):
    m = node.getMass()
    moment = np.asarray(node.getInertia().getMoment(), float)
    if not (math.isfinite(m) and m > 0):
        raise ValueError(f"body '{node.getName()}' has mass {m}: masses must be positive and finite.")
    eig = np.linalg.eigvalsh(0.5 * (moment + moment.T)) if np.all(np.isfinite(moment)) else [np.nan]
    if not np.all(np.isfinite(eig)) or min(eig) <= 0:
        raise ValueError(f"body '{node.getName()}' has a rotational inertia that is not positive "
                         f"definite (eigenvalues {np.round(eig, 12)}).")


@functools.lru_cache(maxsize=256)
def _shape_of_record(text: str):
    """The shape of an attach() record (its JSON, keys sorted). Shapes are values, never changed
    after construction, so every stepper built on nodes with the same record shares one object
    and an intersection's construction-time analysis (linear programs, vertex enumeration) is
    paid once per process: the grasp study builds a stepper per trial (measured: 24 ms of a
    173 ms trial was its stepper's construction, mostly that analysis)."""
    return shp.shape_from_dict(json.loads(text))


def _shapes_of(node, planar: bool) -> list:
    found = []
    for k in range(node.getNumShapeNodes()):
        sn = node.getShapeNode(k)
        name = sn.getName()
        if name.startswith(SHAPE_NODE_PREFIX):
            rec = _parse_record(name)
            compliance = Compliance.from_dict(rec["compliance"]) if "compliance" in rec else None
            found.append(ContactShape(_shape_of_record(json.dumps(rec["shape"], sort_keys=True)),
                                      Friction(**rec["friction"]),
                                      compliance, rec.get("name", name)))
        elif sn.hasCollisionAspect():
            R, c = _placement(sn)
            shape = implicit_from_dart_shape(sn.getShape(), R, c, planar)
            mu = sn.getDynamicsAspect().getFrictionCoeff() if sn.hasDynamicsAspect() else DEFAULT_DART_MU
            found.append(ContactShape(shape, Friction(mu=float(mu)), None, name))
    return found


# --------------------------------------------------------------------------------------------
# FreeJoint convention
# --------------------------------------------------------------------------------------------
def check_free_joint_convention() -> None:
    """Measure dartpy's FreeJoint velocity convention; raise if it is not [omega_w; v_w].

    The stepper assumes (dartpy 6.20): generalized velocity = [angular velocity; origin velocity],
    both in the world frame, world Jacobian of the body origin = I6, and integratePositions doing
    R+ = exp(h [omega]x) R, p+ = p + h v. Earlier wheels (6.16) used body-frame velocities.
    """
    skel = dart.dynamics.Skeleton("implicit_contact_convention_probe")
    _, body = skel.createFreeJointAndBodyNodePair()
    R0 = rotation_exp(np.array([0.3, -0.5, 0.7]))
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R0, [0.1, 0.2, 0.3]
    skel.getJoint(0).setTransform(dart.math.Isometry3(T)) if hasattr(dart.math, "Isometry3") else \
        skel.setPositions(np.concatenate([rotation_log(R0), [0.1, 0.2, 0.3]]))
    w, v, h = np.array([0.4, 1.1, -0.6]), np.array([1.0, -2.0, 0.5]), 0.05
    skel.setVelocities(np.concatenate([w, v]))
    J = skel.getWorldJacobian(body, np.zeros(3))
    skel.integratePositions(h)
    T1 = body.getWorldTransform().matrix()
    ok = (np.allclose(J, np.eye(6), atol=1e-12)
          and np.allclose(T1[:3, :3], rotation_exp(h * w) @ R0, atol=1e-12)
          and np.allclose(T1[:3, 3], np.array([0.1, 0.2, 0.3]) + h * v, atol=1e-12))
    if not ok:
        raise RuntimeError(
            f"this dartpy ({getattr(dart, '__version__', '?')}) uses a FreeJoint velocity convention "
            "other than [omega_world; v_world] with R+ = exp(h w) R: implicit_contact needs "
            "dartpy==6.20.0 (pip install dartpy==6.20.0).")


# --------------------------------------------------------------------------------------------
# SO(3) helpers (numpy only, shared with the formulation)
# --------------------------------------------------------------------------------------------
def rotation_exp(phi: np.ndarray) -> np.ndarray:
    """Rodrigues: exp([phi]x)."""
    phi = np.asarray(phi, float)
    th = math.sqrt(float(phi @ phi))
    K = np.array([[0.0, -phi[2], phi[1]], [phi[2], 0.0, -phi[0]], [-phi[1], phi[0], 0.0]])
    if th < 1e-8:
        return np.eye(3) + K + 0.5 * K @ K
    return np.eye(3) + (math.sin(th) / th) * K + ((1.0 - math.cos(th)) / th**2) * K @ K


def rotation_log(R: np.ndarray) -> np.ndarray:
    c = max(-1.0, min(1.0, (np.trace(R) - 1.0) / 2.0))
    th = math.acos(c)
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if th < 1e-8:
        return 0.5 * w
    return th / (2.0 * math.sin(th)) * w


# --------------------------------------------------------------------------------------------
# State in, state out
# --------------------------------------------------------------------------------------------
@dataclass
class SkeletonState:
    q: np.ndarray
    v: np.ndarray
    M: np.ndarray              # mass matrix at l (+ h D + h^2 K of joint dampers and springs)
    force: np.ndarray          # tau + tau_ext - (Coriolis + gravity) + springs and dampers, at l
    R: np.ndarray | None       # world pose of its first contact body at l (3x3), or None
    p: np.ndarray | None
    bodies: dict = field(default_factory=dict)   # ARTICULATED: body index -> (R, p, J 6 x ndof)


def _spring_damper(skel):
    """Per dof (stiffness K, damping D, rest position), or None if all are zero."""
    k, d, q0 = [], [], []
    for j in range(skel.getNumJoints()):
        joint = skel.getJoint(j)
        for i in range(joint.getNumDofs()):
            k.append(joint.getSpringStiffness(i))
            d.append(joint.getDampingCoefficient(i))
            q0.append(joint.getRestPosition(i))
    k, d, q0 = np.array(k, float), np.array(d, float), np.array(q0, float)
    if not (k.any() or d.any()):
        return None
    return k, d, q0


def _coulomb(skel):
    """Per dof Coulomb joint friction force (joint.getCoulombFriction), or None if all are zero."""
    f = np.array([skel.getJoint(j).getCoulombFriction(i) for j in range(skel.getNumJoints())
                  for i in range(skel.getJoint(j).getNumDofs())], float)
    return f if f.any() else None


def _limits(skel, tol=1e-9):
    """(dofs, lower, upper) of the dofs whose joints enforce position limits with a finite side,
    or None; refuses a skeleton that starts outside them."""
    dofs, lo, hi = [], [], []
    for j in range(skel.getNumJoints()):
        joint = skel.getJoint(j)
        n = joint.getNumDofs()
        if n and joint.areLimitsEnforced():
            for i in range(n):
                a, b = joint.getPositionLowerLimit(i), joint.getPositionUpperLimit(i)
                if not (a <= b) or math.isnan(a) or math.isnan(b):
                    raise ValueError(f"joint '{joint.getName()}' of skeleton '{skel.getName()}' has position "
                                     f"limits [{a}, {b}] on dof {i}: lower must be <= upper.")
                if math.isfinite(a) or math.isfinite(b):
                    q = joint.getPosition(i)
                    if not (a - tol <= q <= b + tol):
                        raise ValueError(f"joint '{joint.getName()}' of skeleton '{skel.getName()}' starts at "
                                         f"{q} on dof {i}, outside its enforced limits [{a}, {b}]; move it "
                                         "inside them.")
                    dofs.append(joint.getIndexInSkeleton(i))
                    lo.append(a)
                    hi.append(b)
    if not dofs:
        return None
    return np.array(dofs, np.int64), np.array(lo, float), np.array(hi, float)


_ONE_DOF_JOINTS = ("RevoluteJoint", "PrismaticJoint", "ScrewJoint")


def _mimic_rows(skel, mimic) -> tuple:
    """(follower dof, leader dof, multiplier, offset) of the given mimic relations whose
    followers are in this skeleton, for the joints DART marks MIMIC, as DART applies them (its URDF
    loader leaves a joint whose leader it cannot find FORCE, and a fixed joint with a <mimic> tag
    a WeldJoint with nothing to move: neither gets a row)."""
    names = {skel.getJoint(j).getName(): j for j in range(skel.getNumJoints())}
    out = []
    for follower, relation in mimic.items():
        if follower not in names:
            continue
        leader, multiplier, offset = relation
        jf = skel.getJoint(names[follower])
        if jf.getNumDofs() == 0 or jf.getActuatorType().name != "MIMIC":
            continue
        if leader not in names:
            raise ValueError(f"mimic joint '{follower}' of skeleton '{skel.getName()}' follows '{leader}', "
                             "which is not a joint of the same skeleton.")
        jl = skel.getJoint(names[leader])
        for jt in (jf, jl):
            if jt.getType() not in _ONE_DOF_JOINTS:
                raise ValueError(f"mimic relation '{follower}' -> '{leader}': joint '{jt.getName()}' is a "
                                 f"{jt.getType()}; mimic joints must be one-dof (revolute, prismatic, screw).")
        if not (math.isfinite(multiplier) and math.isfinite(offset)):
            raise ValueError(f"mimic joint '{follower}': multiplier and offset must be finite.")
        if follower == leader:
            raise ValueError(f"mimic joint '{follower}' cannot follow itself.")
        out.append((jf.getIndexInSkeleton(0), jl.getIndexInSkeleton(0), float(multiplier), float(offset)))
    followers = [r[0] for r in out]
    if set(followers) & {r[1] for r in out}:
        raise ValueError(f"skeleton '{skel.getName()}': a mimic joint follows another mimic joint; point "
                         "each follower at the joint that drives the chain.")
    return tuple(out)


def urdf_mimic_joints(urdf: str) -> dict:
    """{follower joint: (leader joint, multiplier, offset)} of a URDF's <mimic> tags (the text,
    or a path to the file), for ImplicitContactStepper(world, mimic=...): DART's URDF loader
    marks such joints MIMIC but dartpy does not expose the relation."""
    import os
    import xml.etree.ElementTree as ET
    text = open(urdf).read() if os.path.exists(urdf) else urdf
    out = {}
    for joint in ET.fromstring(text).iter("joint"):
        tag = joint.find("mimic")
        if tag is not None:
            out[joint.get("name")] = (tag.get("joint"), float(tag.get("multiplier", 1.0)),
                                      float(tag.get("offset", 0.0)))
    return out


def read_raw(rec: SkeletonRecord, q_out, v_out, tau_out, fext_out, dv_out=None) -> None:
    """What a mobile skeleton carries at l: q, v, its joint forces and external forces (and its
    accelerations, for a snapshot), into the given views (the stepper's world buffers)."""
    skel = rec.skeleton
    q_out[:] = skel.getPositions()
    v_out[:] = skel.getVelocities()
    tau_out[:] = skel.getForces()
    fext_out[:] = skel.getExternalForces()
    if dv_out is not None:
        dv_out[:] = skel.getAccelerations()


def read_state(views, bodies) -> None:
    """read_raw and read_dynamics of every mobile skeleton and read_body of the given bodies in
    one pass: views (skeleton, q, v, tau, fext, M, cg) per mobile skeleton and (BodyRecord, T,
    J or None) per body, each into its buffer (the stepper's world buffers; the step that
    repeats the last one's structure reads DART this way, ImplicitContactStepper._quick_repeat).
    The case: the rolling disc's step, ~46 us, spent ~3 us in the calls around the reads."""
    for skel, q, v, tau, fext, M, cg in views:
        q[:] = skel.getPositions()
        v[:] = skel.getVelocities()
        tau[:] = skel.getForces()
        fext[:] = skel.getExternalForces()
        M[:] = skel.getMassMatrix()
        cg[:] = skel.getCoriolisAndGravityForces()
    for body, T, J in bodies:
        read_body(body, T, J)


def read_dynamics(rec: SkeletonRecord, M_out, cg_out) -> None:
    """M and the Coriolis and gravity forces at l of one mobile skeleton. (The stepper adds its
    joint springs and dampers, implicit as DART treats them, see the module docstring:
    step_kernels.assemble_forces with the coefficients read when it was built, rec.spring_damper;
    reading them costs ~25 us per skeleton.)"""
    skel = rec.skeleton
    M_out[:] = skel.getMassMatrix()
    cg_out[:] = skel.getCoriolisAndGravityForces()


def coriolis_jacobian(rec: SkeletonRecord, v) -> np.ndarray:
    """dc/dv (k, k) of DART's Coriolis forces c(q, v) at the skeleton's q and the velocities v,
    by central differences: c is quadratic in v, so they are exact up to round-off. Leaves the
    skeleton's velocities at v."""
    skel = rec.skeleton
    v = np.array(v, float)
    k = len(v)
    out = np.empty((k, k))
    eps = 1.0
    for i in range(k):
        e = v.copy()
        e[i] += eps
        skel.setVelocities(e)
        cp = np.array(skel.getCoriolisForces())
        e[i] -= 2.0 * eps
        skel.setVelocities(e)
        out[:, i] = (cp - np.array(skel.getCoriolisForces())) / (2.0 * eps)
    skel.setVelocities(v)
    return out


def free_coriolis_jacobian(M, w) -> np.ndarray:
    """dc/dv (6, 6) of DART's Coriolis forces for one rigid body on a FreeJoint, in closed form
    from its mass matrix M at q and its angular velocity w (world frame), where coriolis_jacobian
    takes 12 calls into DART (the derivation: step_kernels.free_coriolis_jacobian, which computes
    it)."""
    out = np.empty((6, 6))
    step_kernels.free_coriolis_jacobian(np.ascontiguousarray(M, dtype=float), np.ascontiguousarray(w, dtype=float), out)
    return out


def read_body(body: BodyRecord, T_out, J_out=None) -> None:
    """A body's world transform at l (4 x 4; and, with J_out (6, k), DART's world Jacobian of
    its origin). (Tried: a root body's transform through its parent joint,
    getParentJoint().getRelativeTransform(), the same matrix bit for bit: 2.35-2.48 against
    2.42-2.65 us for a welded ground, but 14 us against 2.4 for a FreeJoint's body.)"""
    T_out[:] = body.body_node.getTransform().matrix()
    if J_out is not None:
        J_out[:] = body.skeleton.getWorldJacobian(body.body_node, _ORIGIN)


_ORIGIN = np.zeros(3)


def origin_and_jacobian(body: BodyRecord):
    """(origin p (3,), DART's world Jacobian of the origin (6, k), angular rows first) of a mobile
    body now. A FREE body's are its positions' last three and I6 (check_free_joint_convention),
    a PLANAR body's (x, y, 0) and the constant map of [x, y, theta] (z rotation, x and y
    translation): exactly DART's p, and the Jacobians the stepper's rows take for them (DART's own
    carry round-off up to 2e-15), without the two calls into DART (~10 us of a rocking
    ellipsoid's order-2 step)."""
    if body.kind == FREE:
        return body.skeleton.getPositions()[3:6], _EYE6
    if body.kind == PLANAR:
        q = body.skeleton.getPositions()
        return np.array([q[0], q[1], 0.0]), _PLANAR_J
    T = body.body_node.getTransform().matrix()
    return T[:3, 3].copy(), body.skeleton.getWorldJacobian(body.body_node, _ORIGIN)


_EYE6 = np.eye(6)
_EYE6.flags.writeable = False
_PLANAR_J = np.zeros((6, 3))
_PLANAR_J[2, 2] = _PLANAR_J[3, 0] = _PLANAR_J[4, 1] = 1.0
_PLANAR_J.flags.writeable = False


def body_pose(body: BodyRecord):
    T = body.body_node.getWorldTransform().matrix()
    return T[:3, :3].copy(), T[:3, 3].copy()


@dataclass
class WorldSnapshot:
    time: float
    skeletons: list            # (skeleton, q, v, dv, tau) of every skeleton with dofs


def snapshot(world, skeletons=None, arrays=()) -> WorldSnapshot:
    """The world's time and every skeleton's q, v, dv and joint forces, to restore a failed step.
    skeletons: the world's skeletons with dofs not given in arrays (default: all of them);
    arrays: (skeleton, q, v, dv, tau) already read (copied here)."""
    if skeletons is None:
        skeletons = [world.getSkeleton(s) for s in range(world.getNumSkeletons())]
    items = [(sk, q.copy(), v.copy(), dv.copy(), tau.copy()) for sk, q, v, dv, tau in arrays]
    for sk in skeletons:
        items.append((sk, np.array(sk.getPositions()), np.array(sk.getVelocities()),
                      np.array(sk.getAccelerations()), np.array(sk.getForces())))
    return WorldSnapshot(world.getTime(), items)


def restore(world, snap: WorldSnapshot) -> None:
    for sk, q, v, dv, tau in snap.skeletons:
        sk.setPositions(q)
        sk.setVelocities(v)
        sk.setAccelerations(dv)
        sk.setForces(tau)
    world.setTime(snap.time)


def write_velocities_and_integrate(rec: SkeletonRecord, v_next: np.ndarray, v_prev: np.ndarray, h: float,
                                   midpoint: bool = False):
    """Write v+ and let DART integrate q+ = q (+) h v+ (its integrator is the one the formulation
    models); midpoint: q+ = (q (+) h/2 v) (+) h/2 v+, the trapezoidal rule of the quasi-rigid
    'midpoint' scheme."""
    skel = rec.skeleton
    if midpoint:
        skel.setVelocities(v_prev)
        skel.integratePositions(0.5 * h)
        skel.setVelocities(v_next)
        skel.integratePositions(0.5 * h)
    else:
        skel.setVelocities(v_next)
        skel.integratePositions(h)
    skel.setAccelerations((v_next - v_prev) / h)


def finish_step(world, h: float, skeletons=None, t0=None) -> None:
    """What World.step() does after integrating: clear external forces and commands, advance time.
    skeletons: the world's skeletons, if the caller holds them; t0: the world's time before the
    step, if the caller read it."""
    if skeletons is None:
        skeletons = [world.getSkeleton(s) for s in range(world.getNumSkeletons())]
    for sk in skeletons:
        sk.clearExternalForces()
        sk.clearInternalForces()
    world.setTime((world.getTime() if t0 is None else t0) + h)
