"""No heavy tail on the Angers sensors: σ²·N (relative variance times photons) the same from 1e6 to 1e7 photons.

An estimator whose rare, large contributions dominate (photons counted with their whole weight after two
specular reflections, before the twelfth session) reports a σ that grows with N beyond 1/√N: σ²·N rises as
the rare events start to land (median 19.9 at 1e6, 149.5 at 1.6e7 before; measured by the probe
``git show 8f3ec82:benchmarks/heavy_tails.py``).
Issue 23 asks for σ²·N constant within 20 %.  Measured (seed 1): 28.3 at 1e6, 31.7 at 1e7 (+12 %); with the
two-mirror events off, 44.8 and 56.8 (+27 %)."""
import numpy as np
import pytest

from lpy_light.run import simulate
from lpy_light.chamber.scene import load_scene, resolve_scene


@pytest.fixture(scope="module")
def angers():
    ks = simulate.KernelScene(load_scene(resolve_scene("angers")), estimator="nee")
    ks.prune_next_events(threads=2)
    return ks


def sigma2n(ks, photons, seed=1):
    """Mean over the sensors of their relative variance times the photons, from a run of ``photons``."""
    result = simulate.run(ks, photons, seed=seed, threads=2)
    ppfd, std = result.sensors()
    return float(np.mean((std[:, 0] / ppfd[:, 0]) ** 2 * result.photons))


def test_sigma2n_is_constant_from_1e6_to_1e7_photons(angers):
    small, large = sigma2n(angers, 1_000_000), sigma2n(angers, 10_000_000)
    assert abs(large / small - 1.0) < 0.2, (small, large)


def test_without_two_mirror_events_the_tail_returns(angers):
    """The same runs with the events through two mirrors off (those photons counted): σ²·N at 1e7 well above
    its value at 1e6 -- the test above would fail."""
    angers.configure(images2=0.0)
    try:
        small, large = sigma2n(angers, 1_000_000), sigma2n(angers, 10_000_000)
    finally:
        angers.configure(images2=0.25)
    assert large / small > 1.2, (small, large)
