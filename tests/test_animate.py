"""Teaching animations (implicit_contact.animate): frame counts, the drawn contact, input checks.

Oracles: a GIF of a trajectory with n recorded states has ceil(n / stride) frames (counted by
opening it with Pillow); the disc rolling on the ground receives a normal impulse m g h straight
up ([GI] Example 1: the normal impulse while rolling is m g h).
"""
import math

import numpy as np
import pytest
from PIL import Image

from implicit_contact import animate as an
from scenes import disc_rolling, ellipsoid_rocking

STEPS, H = 20, 0.01
P_N_TOL = 1e-9   # [N s] the rolling disc's normal impulse m g h at the solver's tolerance


@pytest.fixture(scope="module")
def disc_traj():
    return disc_rolling.simulate(STEPS * H, H)


def frames_of(path) -> int:
    with Image.open(path) as gif:
        return gif.n_frames


def test_disc_gif_has_one_frame_per_recorded_state(disc_traj, tmp_path):
    bodies = [an.Disc(disc_rolling.RADIUS), an.HalfPlane((0.0, 1.0), 0.0)]
    path = an.animate(disc_traj, bodies, tmp_path / "disc.gif", follow=0)
    assert len(disc_traj.times) == STEPS + 1
    assert frames_of(path) == STEPS + 1


def test_stride_draws_every_kth_state(disc_traj, tmp_path):
    bodies = [an.Disc(disc_rolling.RADIUS), an.HalfPlane((0.0, 1.0), 0.0)]
    path = an.animate(disc_traj, bodies, tmp_path / "disc3.gif", stride=3)
    assert frames_of(path) == math.ceil((STEPS + 1) / 3) == len(an.frame_indices(STEPS + 1, 3))


def test_ellipsoid_projected_on_the_yz_plane(tmp_path):
    traj = ellipsoid_rocking.simulate(5 * H, H)
    path = an.animate(traj, ellipsoid_rocking.animation_bodies(), tmp_path / "ellipsoid.gif", plane="yz")
    assert frames_of(path) == 6


def test_the_disc_is_pushed_straight_up_by_m_g_h(disc_traj):
    (contact,) = an._contacts(disc_traj, STEPS, an.PLANES["xy"])
    a1, a2, start, direction, p_n = contact
    np.testing.assert_allclose(direction, [0.0, 1.0], atol=1e-12)   # the push on the disc, not on the ground
    assert p_n == pytest.approx(disc_rolling.MASS * disc_rolling.G * H, abs=P_N_TOL)
    assert an._contacts(disc_traj, 0, an.PLANES["xy"]) == []         # state 0 has no step behind it


def test_bad_inputs_are_refused(disc_traj, tmp_path):
    with pytest.raises(ValueError, match="plane"):
        an.animate(disc_traj, [an.Disc(1.0)], tmp_path / "x.gif", plane="ab")
    with pytest.raises(ValueError, match="follow"):
        an.animate(disc_traj, [an.HalfPlane((0.0, 1.0))], tmp_path / "x.gif", follow=0)
    with pytest.raises(ValueError, match="stride"):
        an.frame_indices(10, 0)
    with pytest.raises(ValueError, match="radius"):
        an.Disc(-1.0)
