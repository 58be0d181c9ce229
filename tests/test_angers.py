"""The built-in Angers chamber against SEC2 (quick check; the full validation is opt-in)."""
import numpy as np

from lpy_light.run import simulate
from lpy_light.chamber.scene import load_scene


def sec2_counts(path):
    return np.array([int(line.split("=")[1]) for line in open(path) if line.startswith("nb particules")], float)


def test_angers_total_agrees_with_sec2(angers_dir):
    chamber = load_scene(angers_dir / "angers.toml")
    n = 1_000_000
    result = simulate.run(simulate.KernelScene(chamber, "weighted"), n, seed=1)
    photons, std = result.sensors()
    sec2 = sec2_counts(angers_dir / "reference-sec2/mesures.txt")
    assert len(sec2) == len(photons) == 240
    scale = 999999936 / n
    total, total_std = photons[:, 0].sum() * scale, np.sqrt((std[:, 0] ** 2).sum()) * scale
    z = (total - sec2.sum()) / np.hypot(total_std, np.sqrt(sec2.sum()))
    assert abs(z) < 4, "total vs SEC2: %.4f (z = %.2f)" % (total / sec2.sum(), z)
    # power: a 5 % error in the lamps' output would be caught
    assert abs(1.05 * total - sec2.sum()) / np.hypot(total_std, np.sqrt(sec2.sum())) > 4
