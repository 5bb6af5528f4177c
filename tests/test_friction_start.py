"""recovery._must_slide: whether a contact that just got friction rows can stick within the step,
against the closed form for a sphere on a fixed plane."""
import numpy as np
import pytest

from implicit_contact import formulation as fm
from implicit_contact import recovery
from implicit_contact import shapes as shp
from implicit_contact.params import Friction

MASS, RADIUS, MU, H = 2.0, 0.3, 0.4, 0.01
P_N = MASS * 9.81 * H                  # [N s] a resting step's normal impulse
# the tangential Delassus value of a solid sphere's contact point: 1/m + r^2/I = 7 / (2 m)
STICK_LIMIT = MU * P_N * 7.0 / (2.0 * MASS)      # [m/s] the largest slip friction stops in a step


def _sphere_on_plane(slip):
    """A sphere resting on z = 0 (a fixed half-space), its frictionless solution slipping at
    `slip` along x with normal impulse P_N: (problem, z)."""
    sphere = fm.BodyKinematics(fm.FREE, 3, np.eye(3), np.array([0.0, 0.0, RADIUS]), None, H, np.arange(6), MASS)
    ground = fm.BodyKinematics(fm.FIXED, 3, np.eye(3), np.zeros(3), None, H, None)
    inertia = 0.4 * MASS * RADIUS ** 2
    M = np.diag([inertia] * 3 + [MASS] * 3)
    block = fm.SkeletonBlock(M, np.zeros(6), np.zeros(6), 0)
    o1 = fm.ContactObject(0, tuple(shp.Sphere(RADIUS).functions), False)
    o2 = fm.ContactObject(1, tuple(shp.HalfSpace([0, 0, 1], 0.0).functions), True)
    spec = fm.PairSpec("k", o1, o2, 3, Friction(MU), False, 0, np.array([1.0, 0.0, 0.0]), P_N)
    layout = fm.build_layout([6], [spec])
    problem = fm.StepProblem(H, [block], [sphere, ground], [spec], layout)
    z = np.zeros(layout.n)
    z[layout.v_index[0]] = [0.0, 0.0, 0.0, slip, 0.0, 0.0]
    contact = np.zeros(3)
    problem.pack_points(z, 0, contact, contact)
    z[layout.pairs[0].p_n] = 1.0                       # in units of s_p = P_N
    return problem, z


@pytest.mark.parametrize("factor, slides", [(0.98, False), (1.02, True), (0.0, False), (50.0, True)])
def test_a_sphere_must_slide_exactly_when_friction_cannot_stop_its_slip_in_one_step(factor, slides):
    problem, z = _sphere_on_plane(factor * STICK_LIMIT)
    assert problem.unpack_pair(z, 0).p_n == pytest.approx(P_N)
    assert recovery._must_slide(problem, z, 0) is slides
