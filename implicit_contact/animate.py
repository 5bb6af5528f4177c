"""Teaching animations: a Trajectory as a GIF of the bodies, their contact points and normal impulses.

    from implicit_contact import animate as an
    an.animate(traj, [an.Disc(1.0), an.HalfPlane((0.0, 1.0), 0.0)], "disc.gif", follow=0)

What a frame shows (state k of the trajectory, the contacts of the step that ended there):
  * every body, drawn from its pose in ``traj.q``: a planar disc from [x, y, theta]; a sphere or
    an ellipsoid on a FreeJoint from [rotation vector, origin] projected orthographically on a
    coordinate plane (``plane="yz"``: world y to the right, z up); fixed bodies from their given
    placement; a half-plane as a hatched region. A line from the centre to a body-fixed point
    shows the rotation.
  * the closest points a1 (on body a, filled dot) and a2 (on body b, open dot) of every pair of
    the implicit stepper's report (``report.contacts``) that carries a normal impulse p_n > 0;
  * for those, an arrow along the contact normal, pointing into the mobile body (the push it
    receives), with length proportional to p_n: the longest arrow of the animation is
    ``impulse_length`` metres and stands for the largest p_n drawn.
Reports of other steppers (DART's native reports carry points but no impulses) draw no contacts.

Ellipsoid projection: the ellipsoid {x : (x - p)^T A^-1 (x - p) <= 1}, A = R diag(a^2) R^T,
casts on a coordinate plane the ellipse with the 2x2 block of A on those coordinates (the
shadow of a quadric under an orthographic projection P is P A P^T); its eigenvectors give the
axes and sqrt of its eigenvalues the semi-axes.

The GIF is written with matplotlib's PillowWriter (Pillow ships with matplotlib), one frame per
``stride`` recorded states: frames k = 0, stride, 2 stride, ... < len(traj.times).
"""
from __future__ import annotations

from dataclasses import dataclass
import math
from pathlib import Path

import numpy as np

PLANES = {"xy": (0, 1), "yz": (1, 2), "xz": (0, 2)}
_FAR = 1e4  # [m] half-planes are drawn as polygons this far out; the view clips them


# ---------------------------------------------------------------------------------------------
# what to draw
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Disc:
    """A disc on a PlanarJoint (XY plane): q[q_index : q_index + 3] = [x, y, theta]."""
    radius: float
    q_index: int = 0

    def __post_init__(self):
        _check_positive(self.radius, "Disc.radius")


@dataclass(frozen=True)
class HalfPlane:
    """A fixed solid {x : normal . x <= offset} in the drawing plane's coordinates (2D)."""
    normal: tuple
    offset: float = 0.0

    def __post_init__(self):
        n = np.asarray(self.normal, float)
        if n.shape != (2,) or not np.all(np.isfinite(n)) or np.linalg.norm(n) == 0:
            raise ValueError(f"HalfPlane.normal must be a non-zero 2-vector, got {self.normal!r}")


@dataclass(frozen=True)
class Sphere:
    """A sphere: on a FreeJoint (q[q_index : q_index + 6] = [rotation vector, origin]) if q_index
    is given, else fixed with its centre at ``center`` (world frame)."""
    radius: float
    q_index: int | None = None
    center: tuple = (0.0, 0.0, 0.0)

    def __post_init__(self):
        _check_positive(self.radius, "Sphere.radius")


@dataclass(frozen=True)
class Ellipsoid:
    """An ellipsoid with semi-axes (a, b, c) along its body x, y, z: on a FreeJoint if q_index is
    given, else fixed at ``center`` with ``rotation`` (3x3, world from body; None = identity)."""
    semi_axes: tuple
    q_index: int | None = None
    center: tuple = (0.0, 0.0, 0.0)
    rotation: tuple | None = None

    def __post_init__(self):
        a = np.asarray(self.semi_axes, float)
        if a.shape != (3,) or not np.all(a > 0) or not np.all(np.isfinite(a)):
            raise ValueError(f"Ellipsoid.semi_axes must be three positive lengths, got {self.semi_axes!r}")


def frame_indices(n_states: int, stride: int = 1) -> list[int]:
    """The recorded states drawn: 0, stride, 2 stride, ... < n_states."""
    if not (isinstance(stride, int) and stride >= 1):
        raise ValueError(f"stride must be an integer >= 1, got {stride!r}")
    return list(range(0, int(n_states), stride))


# ---------------------------------------------------------------------------------------------
# the animation
# ---------------------------------------------------------------------------------------------
def animate(traj, bodies, path, *, plane: str = "xy", stride: int = 1, fps: int = 25, limits=None,
            follow: int | None = None, window=(6.0, 3.0), title: str = "", impulse_length: float | None = None,
            dpi: int = 80) -> Path:
    """Write ``traj`` as a GIF at ``path``; returns the path.

    bodies: Disc / HalfPlane (2D) or Sphere / Ellipsoid (3D, projected on ``plane``, one of
    "xy", "yz", "xz"; a HalfPlane is then in that plane's coordinates). stride: draw every
    stride-th recorded state. fps: frames per second of the GIF. limits: ((x0, x1), (y0, y1)) [m]
    of the view; default: the mobile bodies' extent over the drawn frames, padded. follow: index
    in ``bodies`` of a mobile body to keep centred in a view of size ``window`` (width, height) [m]
    (overrides limits). impulse_length [m]: length of the longest impulse arrow (default a quarter
    of the view height).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.animation import FuncAnimation, PillowWriter

    if plane not in PLANES:
        raise ValueError(f"plane must be one of {tuple(PLANES)}, got {plane!r}")
    if not bodies:
        raise ValueError("bodies is empty: give at least one Disc, HalfPlane, Sphere or Ellipsoid")
    if follow is not None and not (0 <= follow < len(bodies) and _is_mobile(bodies[follow])):
        raise ValueError(f"follow must index a mobile body of bodies, got {follow!r}")
    axes_idx = PLANES[plane]
    times, q = np.asarray(traj.times, float), np.asarray(traj.q, float)
    frames = frame_indices(len(times), stride)
    if not frames:
        raise ValueError("the trajectory has no recorded state")

    centres = {i: np.array([_centre(b, q[k], axes_idx) for k in frames])
               for i, b in enumerate(bodies) if _is_mobile(b)}
    if follow is None:
        limits = limits or _auto_limits(bodies, centres)
        width, height = limits[0][1] - limits[0][0], limits[1][1] - limits[1][0]
    else:
        width, height = float(window[0]), float(window[1])
    contacts = [_contacts(traj, k, axes_idx) for k in frames]
    largest = max((c[4] for frame in contacts for c in frame), default=0.0)
    impulse_length = 0.25 * height if impulse_length is None else float(impulse_length)

    aspect = width / height
    fig, ax = plt.subplots(figsize=(min(10.0, max(4.0, 4.0 * aspect)), min(8.0, max(3.0, 4.0 / aspect)) + 0.6),
                           layout="constrained")

    def draw(n):
        k = frames[n]
        ax.clear()
        if follow is None:
            ax.set_xlim(*limits[0])
            ax.set_ylim(*limits[1])
        else:
            cx, cy = centres[follow][n]
            ax.set_xlim(cx - width / 2, cx + width / 2)
            ax.set_ylim(cy - height / 2, cy + height / 2)
        ax.set_aspect("equal")
        for body in bodies:
            _draw_body(ax, body, q[k], axes_idx)
        for a1, a2, start, direction, p_n in contacts[n]:
            ax.plot(*a1, "o", color="tab:red", ms=4, zorder=5)                 # on body a: filled
            ax.plot(*a2, "o", color="tab:red", mfc="white", ms=4, zorder=5)    # on body b: open
            if largest > 0:
                length = impulse_length * p_n / largest
                ax.annotate("", xy=start + length * direction, xytext=start, zorder=6,
                            arrowprops=dict(arrowstyle="->", color="tab:red", lw=1.5))
        names = "xyz"
        ax.set_xlabel(f"{names[axes_idx[0]]} [m]")
        ax.set_ylabel(f"{names[axes_idx[1]]} [m]")
        note = f"arrows: normal impulse, longest = {largest:.3g} N s" if largest > 0 else "no contact impulse"
        ax.set_title((title + "\n" if title else "") + f"t = {times[k]:.3f} s   ({note})", fontsize=9)

    animation = FuncAnimation(fig, draw, frames=len(frames), blit=False)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    animation.save(str(path), writer=PillowWriter(fps=fps), dpi=dpi)
    plt.close(fig)
    return path


# ---------------------------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------------------------
def _check_positive(value, name):
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive length [m], got {value!r}")


def _is_mobile(body) -> bool:
    return isinstance(body, Disc) or (isinstance(body, (Sphere, Ellipsoid)) and body.q_index is not None)


def _pose3(body, qk):
    """(R, p) world pose of a 3D body."""
    from scipy.spatial.transform import Rotation

    if body.q_index is None:
        R = np.eye(3) if getattr(body, "rotation", None) is None else np.asarray(body.rotation, float)
        return R, np.asarray(body.center, float)
    block = qk[body.q_index: body.q_index + 6]
    return Rotation.from_rotvec(block[:3]).as_matrix(), block[3:]


def _centre(body, qk, axes_idx) -> np.ndarray:
    if isinstance(body, Disc):
        return qk[body.q_index: body.q_index + 2]
    _, p = _pose3(body, qk)
    return p[list(axes_idx)]


def _extent(body) -> float:
    return body.radius if isinstance(body, (Disc, Sphere)) else float(max(body.semi_axes))


def _auto_limits(bodies, centres):
    mobile = [i for i in centres]
    if not mobile:
        raise ValueError("no mobile body to frame: give limits=((x0, x1), (y0, y1))")
    lo = np.min([centres[i].min(axis=0) - _extent(bodies[i]) for i in mobile], axis=0)
    hi = np.max([centres[i].max(axis=0) + _extent(bodies[i]) for i in mobile], axis=0)
    pad = 0.3 * max(hi - lo)
    return (lo[0] - pad, hi[0] + pad), (lo[1] - pad, hi[1] + pad)


def _draw_body(ax, body, qk, axes_idx):
    from matplotlib import patches

    if isinstance(body, HalfPlane):
        n = np.asarray(body.normal, float) / np.linalg.norm(body.normal)
        t = np.array([-n[1], n[0]])
        base = n * body.offset / np.linalg.norm(body.normal)
        corners = [base - _FAR * t, base + _FAR * t, base + _FAR * t - _FAR * n, base - _FAR * t - _FAR * n]
        ax.add_patch(patches.Polygon(corners, closed=True, facecolor="0.85", edgecolor="0.3", hatch="//"))
        return
    if isinstance(body, Disc):
        x, y, theta = qk[body.q_index: body.q_index + 3]
        ax.add_patch(patches.Circle((x, y), body.radius, facecolor="tab:blue", alpha=0.35, edgecolor="tab:blue"))
        ax.plot([x, x + body.radius * math.cos(theta)], [y, y + body.radius * math.sin(theta)], color="tab:blue")
        return
    R, p = _pose3(body, qk)
    idx = list(axes_idx)
    centre = p[idx]
    mobile = body.q_index is not None
    colour = "tab:blue" if mobile else "0.5"
    semi = np.full(3, body.radius) if isinstance(body, Sphere) else np.asarray(body.semi_axes, float)
    shadow = (R * semi**2) @ R.T                     # A = R diag(a^2) R^T
    values, vectors = np.linalg.eigh(shadow[np.ix_(idx, idx)])
    angle = math.degrees(math.atan2(vectors[1, 1], vectors[0, 1]))
    ax.add_patch(patches.Ellipse(centre, 2 * math.sqrt(values[1]), 2 * math.sqrt(values[0]), angle=angle,
                                 facecolor=colour, alpha=0.35 if mobile else 0.2, edgecolor=colour))
    if mobile:  # the body axes, projected: they show the rotation
        for axis in range(3):
            tip = p + R[:, axis] * semi[axis]
            ax.plot([centre[0], tip[idx[0]]], [centre[1], tip[idx[1]]], color=colour, lw=0.8)


def _contacts(traj, k, axes_idx):
    """(a1, a2, arrow start, arrow direction, p_n) in the drawing plane for the pairs with p_n > 0
    in the step that ended at state k."""
    if k == 0 or k - 1 >= len(traj.reports):
        return []
    out = []
    for c in getattr(traj.reports[k - 1], "contacts", ()):
        p_n = getattr(c, "p_n", None)
        if p_n is None or not p_n > 0:
            continue
        a1, a2, n = (np.asarray(v, float) for v in (c.a1, c.a2, c.normal))
        if a1.size == 3:
            idx = list(axes_idx)
            a1, a2, n = a1[idx], a2[idx], n[idx]
        # the normal points from body a into body b: b is pushed along +n, a along -n
        direction, start = (n, a2) if _mobile_node(c.body_b) else (-n, a1)
        norm = np.linalg.norm(direction)
        direction = direction / norm if norm > 0 else direction
        out.append((a1, a2, start, direction, float(p_n)))
    return out


def _mobile_node(node) -> bool:
    try:
        skeleton = node.getSkeleton()
        return skeleton.isMobile() and skeleton.getNumDofs() > 0
    except AttributeError:
        return True
