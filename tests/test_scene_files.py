"""The shipped scenes' defaults show what they are about."""
import pytest

from taichi_soft.sim.scene import load_scene


def test_the_sphere_scene_ends_soon_after_the_cube_leaves_the_ball(make_sim):
    """The ball has no floor around it: the default run used to end with 1.5-2 s of the cube falling
    through empty sky. It now ends within 0.8 s of the cube's last contact with the ball."""
    sim = make_sim("sphere")
    duration = load_scene("sphere").sim["duration"]
    last_contact, t = None, 0.0
    while t < duration - 1e-9:
        sim.advance(100)
        t = sim.time
        if sim.measure()["min_terrain_distance"] < 0.05:
            last_contact = t
    assert not sim.diverged and t == pytest.approx(duration)
    assert last_contact is not None and duration - 0.8 <= last_contact < duration - 0.2
