"""fast_mass_spring's contact solve under held particles: ``contact_solve = auto`` follows the
springs' stiffness at the step (its own module: a fresh Taichi runtime, whose field trees the
other implicit tests' simulations have used up)."""
import numpy as np


def test_fast_mass_spring_auto_contact_solve_follows_the_springs_stiffness():
    """``contact_solve = auto`` is the scaled step on soft springs and PCG on stiff ones
    (h^2 k / m above 10): bit for bit the same steps as the choice it stands for, and a stiff cube
    pushed across the plane then slides (it stopped within centimetres with the scaled step)."""
    from taichi_soft.bench import precision as P
    from taichi_soft.bench.plausibility import push_run

    scene, sets, _ = push_run(True)
    sims = {solve: P.build(scene, sets, "fast_mass_spring", {"contact_solve": solve}) for solve in ("auto", "scaled", "pcg")}
    base = sims["auto"].model.group_k.to_numpy().copy()
    for scale, same_as in ((1.0, "scaled"), (100.0, "pcg")):
        ends = {}
        for solve in ("auto", same_as):
            sim = sims[solve]
            P.set_stiffness(sim, scale, base)  # through the model: the matrix and the choice follow
            sim.reset()
            sim.set_dt(1 / 30)
            sim.advance(6)
            ends[solve] = sim.state.x.to_numpy()
        assert np.array_equal(ends["auto"], ends[same_as]), scale
        slid = ends["auto"][:, 0].mean()
        assert slid > 0.5, (scale, slid)  # Coulomb: 3 m/s x 0.2 s - mu g (0.2 s)^2 / 2 = 0.54 m
