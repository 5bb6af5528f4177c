r"""Order 2: a split step after nonsmooth RATTLE, geometrically implicit (StepperOptions(order=2)).

[GI]'s step (order 1) applies the whole impulse of a step in the geometry at l+1 and moves the
bodies with the velocity at l+1: first order, and dissipative wherever the contact point moves
over varying curvature (a rocking ellipsoid). Nonsmooth RATTLE (Breuling, Capobianco, Eugster &
Leine, Nonlinear Analysis: Hybrid Systems 52, 2024) splits a step into two impulses: the first
applied in the geometry at l, the second in the geometry at l+1, with the positions moved by the
velocity in between. Written for this package's bodies (q, v, M, f as DART has them; W the
contact Jacobian of a pair's frame n, t, o and its torsion row; R1 and P in units of the pair's
s_p = m max(h g_ref, IMPULSE_SPEED), as [GI]'s unknowns), one step of h is

stage 1, one geometrically implicit MCP with [GI]'s unknowns (u in place of v^{l+1}):

    M(q) (u - v) = h/2 f(q, u) + W(q)^T R1                                           (R1)
    q+ = q (+) h u                           (DART's integrator, as [GI] eq 21)       (R2)
    a1, a2: the closest points at q+, [GI] (15)-(18);  0 <= R1_n _|_ gap(q+) >= 0 (19) (R3)
    R1's friction: [GI] (21)-(22) with the slip (W_t(q) + W_t(q+))^T u / 2            (R4)

stage 2, one MCP at the fixed geometry q+ (the contacts closed at q+, gap <= tolerance):

    M(q+) (v+ - u) = h/2 f(q+, u) + W(q+)^T (P - R1)                                 (R5)
    0 <= P_n _|_ W_n(q+)^T v+ >= 0           (Newton's impact law, restitution 0)     (R6)
    P's friction: [GI] (21)-(22) with the slip W_t(q+)^T v+ and the total P_n         (R7)
    an open contact (R1 = 0 by (R3)) keeps P = R1 = 0                                 (R8)

Stage 1 is [GI]'s problem with two changes in its pair rows (rows/contact.py, P_SPLIT): the
impulse enters the Newton-Euler rows through the frame and levers at l (a constant W(q), eq R1),
and the friction rows see the mean slip (R4), and two in its skeleton rows: the force is
h/2 f(q, u) linearised about v, h/2 (f(q, v) + df/dv (u - v)), that is M + h/2 dc/dv in place
of M (c: DART's Coriolis forces, quadratic in v, so its central difference is exact) and h/2 f
in place of h f; the error of the linearisation is O(h |u - v|^2) = O(h^3). Stage 2's rows are
linear in v+ and P but for the friction rows (this module: Stage2).

Why these choices (each measured on a 2D prototype first, see issue 14):
* the frame at l in (R1) and at l+1 in (R5) is the trapezoidal rule for the contact force: with
  the whole impulse at l+1 the scheme stays first order;
* the mean slip (R4): with either one-sided tangent row, stage 1's friction is first order;
* f at the half-step velocity in (R1): with f(q, v) the velocity-dependent forces (gyroscopic
  torques, Coriolis) are first order.
In free flight (R1), (R2), (R5) are the velocity Verlet scheme on DART's configuration space
(second order); an impact is inelastic through (R6), and (R7) keeps the total friction maximally
dissipative against the slip at the end of the step. The end-of-step guarantees of [GI] hold:
closest points and non-penetration at q+ are stage 1's rows.

Joint springs and dampers (per dof stiffness K, damping D, rest position q_r; DART and order 1
treat them implicitly, M + h D + h^2 K, first order) take the implicit midpoint rule in both
stages: in (R1) and (R5) the force f includes

    - K (q + h/2 u - q_r) - D u,      q + h/2 u = (q + q+) / 2                          (R9)

(stage 1: M + h/2 dc/dv + h/2 D + h^2/4 K in place of M; stage 2: known terms). For a linear
oscillator the split step is then the implicit midpoint rule: second order, A-stable, and its
energy v M v / 2 + K (q - q_r)^2 / 2 kept to round-off. The midpoint rule multiplies a damped
velocity by (1 - a) / (1 + a) per step, a = h D / (2 M): for a damper stiff for its dof (a > 1,
a light finger link's damper at h = 1e-3) the factor turns negative and tends to -1, the
velocity rings. Such a damper (h D_i / 2 > STIFF_DAMPER M_ii, M at q+) acts at v+ in stage 2:

    (M + h/2 D_i) v+ in (R5) for that dof, D_i u left out of (R9) there               (R10)

that is a factor 1 / (1 + a)^2, L-stable and first order in that dof (step_kernels.
split_end_forces).

Quasi-rigid layers ([GI] Sec. 5; rows/contact.py, eqs 35, 49, 55: a spring k and damper c over
a rigid core, deflection delta, largest deflection delta_max). The layer's impulse over the step
is the implicit midpoint rule's, with delta+ the deflection at q+ (stage 1's unknown),

    S = h k (delta + delta+) / 2 + c (delta+ - delta)                                  (R11)

whatever Compliance.scheme says (it selects order 1's form of eq 49). Stage 1 applies half of it
with the core's impulse: p_n = p_nr + S / 2 in (R1) (eq 49 with h / 2 and c / 2 in place of h and
c: PairSpec.layer_share), and the core's position-level Signorini condition (55) at q+. Stage 2
applies the other half, known after stage 1, and the core's total impulse P_c:

    P_n = S + P_c,   0 <= P_c _|_ n . v_rel(v+) >= 0 if the core is closed at q+
                     (delta_max - delta+ <= tolerance or p_nr > 0), else P_c = 0       (R12)
    P's friction: (R7) on the whole P_n                                                (R13)

For a linear undamped layer in a fixed frame the two halves make u = (v + v+) / 2, q+ - q = h u:
the implicit midpoint rule, which keeps the energy of flight and spring (up to the engaging and
releasing within a step), and (R12) makes a hit on the core plastic (order 1's "midpoint" scheme
bounces off it instead, params.Compliance). As for a joint damper (R10), the midpoint rule rings
when the layer's damper is stiff for the step, a = h c / (2 m) > STIFF_DAMPER (m: the pair's
reduced mass): a ball landing on a critically damped layer of k = 1e8 N/m (a = 10 at h = 1e-3)
bounced off 4 mm high where the converged run rises 0.17 mm. Such a layer's damper acts at v+
in stage 2, as a stiff joint damper's (R10): stage 2's half of c (delta+ - delta) / 2 in S is
replaced by the damper's impulse at the end velocity,

    P_n = S - c (delta+ - delta) / 2 - h/2 c n . v_rel(v+) + P_c                      (R14)

(stage 1's half, c (delta+ - delta) / 2 = h/2 c (the compression rate at u), is backward Euler
already): a factor 1 / (1 + a)^2 on the layer's velocity, L-stable, first order in the layer,
and a body at rest on it keeps v+ = 0. Across the layer the frame is split like a rigid
pair's (R1, R5). A compliant face on a face spreads the layer's load over its patch's vertices
in stage 2 where the face does not turn into the layer (rows/velocity.py: its point's unknown is
the loaded vertices' common normal velocity): with the load at stage 1's point, which sits
wherever it cancels the last step's spin, a box at rest on a layer rocked at +-0.0075 rad/s
from step to step, its positions still.

The start frame of a pair (n0, t0, o0 and the levers r_b0 = a_b - p_b at l) comes from the last
step's solution when the pair persists (its closest points at l+1 are the points at l now), else
from a static closest-point solve at l (stepper.py).

The cases the equations above leave open, and what the step does:
* an impact (a pair open at l): the frame at l is that of the nearest points before the landing,
  not where it lands, and a nearly flat body (a superquadric of exponent 6 dropped on the ground)
  gained up to 0.017 J in a landing step with its impulse there. An open pair takes stage 1's
  impulse at its point at q+, as [GI] does; the pairs touching at l keep the split.
* a face on a face (two faceted pieces, a patch; measured on a DART box): with its impulse at a fixed point at l, stage 1
  has nothing that places its equivalent contact point at q+ (the point is undetermined on the
  face and Newton stalled: a box resting on the ground failed its first step). Such a pair takes
  stage 1's impulse at its point at q+, as [GI] does; in stage 2 its normal load is carried by its
  patch's vertices at q+ (a single point cannot resist tipping at the velocity level: a sliding box
  tumbled) and one friction point sees the whole load (rows/velocity.py). Flat contact has no
  curvature for the frame at l to correct.
* a split stage 1 that does not converge is solved again with every pair unsplit (as [GI],
  at half the force): a nearly flat face rocking on the ground (a superquadric of exponent 10
  dropped) has the undetermined point of a face on a face, and Newton stalled at h / 16.
* joint rows (joint_rows.py): stage 1 has [GI]'s rows with the friction bound h/2 f; stage 2 a
  velocity-level row per friction dof (the total impulse within h f, opposite the end velocity),
  per mimic relation (held at the end velocity) and per limit closed at q+ (end velocity >= 0).
"""
from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

from . import ncp
from ._jit import lean_kernel
from . import step_kernels
from . import step_solver
from .memory import _tangents
from .rows import velocity as rv

_NO_FLOATS = np.zeros(0)   # (Stage2 without joint rows; never written)
STIFF_DAMPER = 1.0   # a = h D_i / (2 M_ii) above which a joint damper acts at v+ in stage 2 (R10)


def stiff_layer(compliance, h, mass) -> bool:
    """Whether a quasi-rigid layer's damper is stiff for the step, h c / (2 mass) > STIFF_DAMPER
    (mass: the pair's reduced mass): its stage-2 half then acts at v+ (R14)."""
    return h * compliance.c_n > 2.0 * STIFF_DAMPER * mass


@lean_kernel
def start_frame(a1, a2, normal, axis, p1, p2, dim, out):
    """A pair's frame at l as rows/contact.py's Q_N0.. columns read it, into out (15,): n (unit,
    body 1 into body 2), t, o by the pair's Gram-Schmidt on its tangent axis (memory._tangents, as
    rows/contact.py), levers a1 - p1, a2 - p2 (p_b: the body origins at l). a1, a2, normal: dim
    entries; p1, p2, axis: 3 (axis unread in 2D). (Compiled: this runs for every split pair of
    every step.)"""
    for i in range(15):
        out[i] = 0.0
    nx, ny = normal[0], normal[1]
    nz = normal[2] if dim == 3 else 0.0
    s = 1.0 / math.sqrt(nx * nx + ny * ny + nz * nz)
    out[0], out[1], out[2] = nx * s, ny * s, nz * s
    if dim == 3:
        _tangents(out[0:3], axis, out[3:6], out[6:9])
    else:
        out[3], out[4] = -out[1], out[0]
    for i in range(dim):
        out[9 + i] = a1[i] - p1[i]
        out[12 + i] = a2[i] - p2[i]
    if dim == 2:
        out[11], out[14] = -p1[2], -p2[2]


@dataclass
class ClosedPair:
    """A contact closed at q+, as stage 2 reads it: its frame at q+ and stage 1's impulse."""
    bodies: tuple          # (index into Stage2's bodies or -1 for a fixed body) for body 1, body 2
    a: tuple               # (a1, a2) world points at q+
    n: np.ndarray
    t: np.ndarray
    o: np.ndarray
    dim: int
    mu: float
    e_t: float
    e_o: float
    e_r: float             # > 0: the pair has a torsion row
    s_p: float
    R1: np.ndarray         # stage 1's (p_n, p_t, p_o, p~_r) in units of s_p (zeros where absent)
    sigma1: float
    known: bool = False    # no unknowns: only its R1 enters (R5) (a patch's stage-1 point, see Stage2)
    start_n: float = -1.0  # the start of its P_n (default 2 R1_n, the trapezoidal guess R2 = R1)
    vertices: int = 0      # a patch's friction point: this many frictionless vertex pairs follow
    load: float = 0.0      # a quasi-rigid pair: its layer's impulse over the step S (R11), in units of
    #                        s_p; its P_n unknown is then the core's, P_n = S + P_c (R12)
    core_open: bool = False  # a quasi-rigid pair whose core is open at q+: P_c = 0 (R12)
    damp: float = 0.0      # a stiff layer's damper at v+: P_n -= damp n . v_rel(v+) (R14; s_p s/m)
    layered: bool = False  # a quasi-rigid pair (load, core_open, damp apply)

    @property
    def layered_patch(self) -> bool:
        """A quasi-rigid face on a face's friction point: its vertices share the layer's load."""
        return self.vertices > 0 and self.layered

    @property
    def friction(self) -> bool:
        return self.mu > 0.0


class Stage2:
    """The MCP of (R5)-(R7) over x = [v+ of the skeletons; per closed pair P_n, then, with
    friction, P_t (P_o in 3D) (P~_r with torsion) and sigma], impulses in units of s_p; its rows
    are rows/velocity.py's kernels.

    skeletons: per skeleton (M(q+) (k, k), u (k,), h/2 f(q+, u) (k,)), its columns contiguous in
    that order; bodies: per body (first column of its skeleton, DART's world Jacobian of its
    origin at q+ (6, k), angular rows first, its origin p at q+).

    A face on a face (two faceted pieces touching along a segment or an area) is, in stage 2, its
    friction point (stage 1's equivalent contact point at q+, with its friction and torsion rows)
    followed by one frictionless pair per vertex of its patch at q+ (rows/velocity.py), so that the
    normal load can move within the patch (a single point cannot resist tipping at the velocity
    level) while friction sees the patch's whole load; its stage-1 impulse R1 is a known pair
    (known=True) whose W^T R1 moves into the right-hand side. A quasi-rigid pair's unknown P_n is
    its core's impulse, its layer's (ClosedPair.load) added in the rows (R12, R13); a quasi-rigid
    face on a face has its vertices share the layer's load where the face does not turn into the
    layer, its point's unknown their common normal velocity (rows/velocity.py)."""

    def __init__(self, skeletons, bodies, pairs, joints=()):
        """joints: per joint row (g over all of x's velocity columns (nv,), unit, lower, upper,
        stage 1's generalized impulse along g) (rows/velocity.py)."""
        self.pairs = list(pairs)
        blocks, at = [], 0
        for M, _, _ in skeletons:
            blocks.append((at, len(M)))
            at += len(M)
        self.nv = at
        self.M = np.zeros((at, at))
        self.u = np.zeros(at)
        self.hf = np.zeros(at)
        self._blocks = np.array(blocks, np.int64).reshape(-1, 2)
        everything = self.pairs
        npairs, nb = len(everything), len(bodies)
        self._bk = np.array([b[1].shape[1] for b in bodies], np.int64)
        kmax = max(1, int(self._bk.max())) if nb else 1
        self._bcol = np.array([b[0] for b in bodies], np.int64)
        self._bJ = np.zeros((nb, 6, kmax))
        self._bp = np.zeros((nb, 3))
        self._ends = np.array([cp.bodies for cp in everything], np.int64).reshape(npairs, 2)
        self._a = np.zeros((npairs, 2, 3))
        self._frame = np.zeros((npairs, 3, 3))
        G = np.zeros((npairs, 4, at))
        self._geometry(skeletons, bodies, everything, G)
        keep = [i for i, cp in enumerate(everything) if not cp.known]
        if len(keep) == npairs:
            self.G = G
        else:
            for cp, g in zip(everything, G):
                if cp.known:      # (R5)'s - W^T (-R1) of a patch's stage-1 point: into h/2 f
                    self.hf -= cp.s_p * (g[0] * cp.R1[0] + g[1] * cp.R1[1] + g[2] * cp.R1[2] + cp.e_r * g[3] * cp.R1[3])
            self.pairs = [everything[i] for i in keep]
            self.G = np.ascontiguousarray(G[keep]).reshape(len(keep), 4, self.nv)
        npairs = len(self.pairs)
        self.pi = np.zeros((npairs, rv.NVI), np.int64)
        self.pf = np.zeros((npairs, rv.NVF))
        self._pair_parameters()
        lo, hi = [-np.inf] * at, [np.inf] * at
        parent, left = -1, 0
        for k, cp in enumerate(self.pairs):
            nt = (cp.dim - 1) if cp.friction else 0
            nr = 1 if (cp.friction and cp.dim == 3 and cp.e_r > 0.0) else 0
            ns = 1 if cp.friction else 0
            self.pi[k] = (at, nt, nr, ns, cp.vertices, int(cp.core_open), int(cp.layered_patch),
                          parent if left > 0 else -1)
            left -= 1
            if cp.vertices:            # (a layered patch's vertices refer to its point's column)
                parent, left = (at if cp.layered_patch else -1), cp.vertices
            free = cp.core_open or (cp.vertices and not cp.layered_patch)
            lo += [-np.inf if free else 0.0] + [-np.inf] * (nt + nr) + [0.0] * ns
            hi += [np.inf] * (1 + nt + nr + ns)
            at += 1 + nt + nr + ns
        nj = len(joints)
        if nj:
            self.jg = np.array([j[0] for j in joints], float).reshape(nj, self.nv)
            self.ju = np.array([j[1] for j in joints], float)
            self.jk = np.array([j[4] for j in joints], float)
            lo += [float(j[2]) for j in joints]
            hi += [float(j[3]) for j in joints]
        else:
            self.jg, self.ju, self.jk = np.zeros((0, self.nv)), _NO_FLOATS, _NO_FLOATS
        self.jcol = np.arange(at, at + nj, dtype=np.int64)
        at += nj
        self.n = at
        self.lower, self.upper = np.array(lo, float), np.array(hi, float)
        self._F, self._J = np.zeros(at), np.zeros((at, at))
        # rigid points only, no joint rows: refresh() can take the next step's stage 2 in place
        self._plain = nj == 0 and len(keep) == len(everything) and not any(cp.vertices or cp.layered
                                                                            for cp in self.pairs)

    def refresh(self, skeletons, bodies, pairs) -> bool:
        """Take the stage 2 of (skeletons, bodies, pairs), as __init__ reads them, in place when its
        structure is this one's: the same skeleton blocks and bodies, the same pairs between the
        same bodies with the same rows, rigid points only, no joint rows (a rolling or rocking body
        step after step: __init__ was a sixth of its split step). False, unchanged, otherwise.
        The arrays are then what __init__ would make of them, entry for entry."""
        if (not self._plain or len(pairs) != len(self.pairs) or len(bodies) != len(self._bcol)
                or len(skeletons) != len(self._blocks)):
            return False
        for cp, old in zip(pairs, self.pairs):
            if (cp.known or cp.vertices or cp.layered or cp.bodies != old.bodies or cp.dim != old.dim
                    or cp.friction != old.friction or (cp.e_r > 0.0) != (old.e_r > 0.0)):
                return False
        for (_, k), (M, _, _) in zip(self._blocks.tolist(), skeletons):
            if len(M) != k:
                return False
        for (col, J, _), c, k in zip(bodies, self._bcol.tolist(), self._bk.tolist()):
            if col != c or J.shape[1] != k:
                return False
        self.pairs = list(pairs)
        self._geometry(skeletons, bodies, self.pairs, self.G)
        self._pair_parameters()
        return True

    def _geometry(self, skeletons, bodies, pairs, G):
        """M, u, h/2 f and the row scale of the skeletons, the bodies' Jacobians and origins, the
        pairs' points and frames, and their rows G (rows/velocity.py) over all of pairs."""
        for (c, k), (M, u, hf) in zip(self._blocks.tolist(), skeletons):
            self.M[c:c + k, c:c + k] = M
            self.u[c:c + k], self.hf[c:c + k] = u, hf
        self.scale = np.array([1e300 if m <= 1e-300 else 1.0 / m for m in self.M.diagonal().tolist()])   # (NaN stays)
        for i, (_, J, p) in enumerate(bodies):
            self._bJ[i, :, :J.shape[1]], self._bp[i] = J, p
        for i, cp in enumerate(pairs):
            self._a[i, 0], self._a[i, 1] = cp.a
            self._frame[i, 0], self._frame[i, 1], self._frame[i, 2] = cp.n, cp.t, cp.o
        rv.velocity_rows(self._ends, self._a, self._frame, self._bcol, self._bk, self._bJ, self._bp, G)

    def _pair_parameters(self):
        """pf (rows/velocity.py) of the pairs."""
        pf = self.pf
        for k, cp in enumerate(self.pairs):
            row = pf[k]
            row[rv.V_MU], row[rv.V_ET], row[rv.V_EO], row[rv.V_ER], row[rv.V_SP] = cp.mu, cp.e_t, cp.e_o, cp.e_r, cp.s_p
            row[rv.V_R1:rv.V_R1 + 4] = cp.R1
            row[rv.V_LOAD], row[rv.V_DAMP] = cp.load, cp.damp

    def fun(self, x):
        rv.stage2_rows(x, self.M, self.u, self.hf, self.scale, self.G, self.pi, self.pf, self.jg, self.ju, self.jk,
                       self.jcol, self._F, self._J, False)
        return self._F.copy()

    def jac(self, x):
        rv.stage2_rows(x, self.M, self.u, self.hf, self.scale, self.G, self.pi, self.pf, self.jg, self.ju, self.jk,
                       self.jcol, self._F, self._J, True)
        return self._J.copy()

    def start(self) -> np.ndarray:
        """The free half kick for v+, twice stage 1's impulse (the trapezoidal guess R2 = R1) and
        stage 1's sigma."""
        x = np.zeros(self.n)
        step_kernels.block_kicks(self.M, self.u, self.hf, self._blocks, x)   # (M: block diagonal)
        for cp, (c, nt, nr, ns, *_) in zip(self.pairs, self.pi):
            m = 1 + nt + nr
            x[c:c + 1 + nt] = 2.0 * cp.R1[:1 + nt]
            if nr:
                x[c + 1 + nt] = 2.0 * cp.R1[3]
            if cp.start_n >= 0.0:
                x[c] = cp.start_n
            if ns:
                x[c + m] = cp.sigma1
        for c, u_r, k_r in zip(self.jcol, self.ju, self.jk):
            x[c] = 2.0 * k_r / u_r if u_r > 0.0 else 0.0
        return x

    def cold_start(self) -> np.ndarray:
        """start() with zero impulses (sigma kept)."""
        x = self.start()
        for cp, (c, nt, nr, ns, *_) in zip(self.pairs, self.pi):
            x[c:c + 1 + nt + nr] = 0.0
        x[self.jcol] = 0.0
        return x

    def solve(self, options: ncp.SolverOptions, converged_at: float | None = None, budget=None):
        """ncp.solve_mcp on (R5)-(R7); its starts and recoveries, in order, each tried when the
        one before did not converge (measured: boxes and prisms landing on a face or a corner in
        the face-contact campaign, whose stage 2 stopped at the iteration cap from start()):
          1. start(): the trapezoidal guess;
          2. cold_start(): zero impulses;
          3. proximal(): the impulse rows damped by eps (x - x_k), eps = 1, 0.1, 0.01, then
             undamped from there (two captured stage 2s of --repro 1568136232,land,box,
             0.000174883..., a face and a corner landing, converged so after both starts had
             stopped at 50 iterations; the corner's impulses ~1e3 s_p reach a natural residual
             of 9e-13, round-off, within the solver's tolerance).
        Returns the first result that converges (or whose residual is at most converged_at), else
        the one with the smallest residual. budget: the step's (budget.Budget), checked before
        and charged after every solve; None: no limit."""
        best = None
        for attempt in (self.start, self.cold_start, None):
            if attempt is None:
                res = self.proximal(options, budget=budget)
            else:
                res = _charged(budget, options, lambda o: step_solver.solve_stage2(self, attempt(), o))
            if res.success or (converged_at is not None and res.residual <= converged_at):
                return res
            if best is None or res.residual < best.residual:
                best = res
        return best

    def proximal(self, options, steps=(1.0, 1e-1, 1e-2), outer=100, budget=None):
        """The proximal-point recovery of solve(): for each eps, up to `outer` solves of
        F(x) + eps D (x - x_k) = 0 (D: 1 on the impulse unknowns) from and around x_k, then the
        undamped problem from the last x_k; returns that last solve's result."""
        mask = np.zeros(self.n)
        mask[self.nv:] = 1.0
        x = self.cold_start()
        for eps in steps:
            for _ in range(outer):
                xk = x.copy()
                res = _charged(budget, options, lambda o: ncp.solve_mcp(
                    lambda z: self.fun(z) + eps * mask * (z - xk), lambda z: self.jac(z) + eps * np.diag(mask),
                    x, self.lower, self.upper, o))
                if not np.all(np.isfinite(res.x)):
                    break
                x = res.x
                if np.max(np.abs(x - xk)) <= 1e-9 * (1.0 + np.max(np.abs(x))):
                    break
        return _charged(budget, options, lambda o: ncp.solve_mcp(self.fun, self.jac, x, self.lower, self.upper, o))

    def impulses(self, x):
        """Per closed pair its total (P_n, P_t, P_o, P~_r) in units of s_p (a quasi-rigid pair's
        P_n: its layer's and its core's; a patch's point: its vertices')."""
        out = []
        for k, (cp, (c, nt, nr, ns, *_)) in enumerate(zip(self.pairs, self.pi)):
            P = np.zeros(4)
            if cp.vertices:
                P[0] = sum(float(x[self.pi[i, 0]]) for i in range(k + 1, k + 1 + cp.vertices))
            else:
                P[0] = x[c] + cp.load - (cp.damp * float(self.G[k, 0] @ x[:self.nv]) if cp.damp else 0.0)
            P[1:1 + nt] = x[c + 1:c + 1 + nt]
            if nr:
                P[3] = x[c + 1 + nt]
            out.append(P)
        return out


    def core_impulses(self, x, totals):
        """Per closed pair the normal impulse of its rigid core (R12), in units of s_p, from x and
        the pairs' total impulses (impulses(x)): all of a rigid pair's P_n; none with the core open;
        a layered patch's vertices' sum less the layer's L - beta w (w: its point's unknown); else
        the pair's normal unknown."""
        cores = []
        for cp, (c, *_), P in zip(self.pairs, self.pi, totals):
            if not cp.layered:
                cores.append(P[0])
            elif cp.core_open:
                cores.append(0.0)
            elif cp.layered_patch:
                cores.append(P[0] - (cp.load - cp.damp * float(x[c])))
            else:
                cores.append(float(x[c]))
        return cores


def _charged(budget, options, solve):
    """solve(options) within the step's budget (budget.py; None: no limit)."""
    if budget is None:
        return solve(options)
    res = solve(budget.admit(options))
    budget.spend(res.iterations)
    return res
