"""A first run's compile of the kernel is said on the progress line, and kept out of the photon rate and ETA."""
import io
import time

from lpy_light.estimators import kernel_scene
from lpy_light.run import simulate
from lpy_light.chamber.scene import load_scene

from scenes import box, lamp_rectangle, write_scene


def _kscene(tmp_path):
    rad = ("void plastic grey\n0\n0\n5 .5 .5 .5 0 0\n\nvoid light lamp\n0\n0\n3 10 10 10\n\n"
           + box("grey", (0, 0, 0), (1000, 1000, 1100)) + lamp_rectangle("lamp", (500, 500), 100, 1000))
    return simulate.KernelScene(load_scene(write_scene(tmp_path, rad, [(500, 500, 500, 50, 0, 0, 1)])), "weighted")


class _SlowFirstTrace:
    """A kernel scene whose first trace takes ``delay`` s more, as numba's compile does."""

    def __init__(self, kscene, delay):
        self._k, self._delay = kscene, delay

    def __getattr__(self, name):
        return getattr(self._k, name)

    def trace(self, *args, **kw):
        if self._delay:
            time.sleep(self._delay)
            self._delay = 0.0
        return self._k.trace(*args, **kw)


def test_compile_is_named_and_not_counted_as_tracing(tmp_path, monkeypatch):
    """Breaks if the progress line gives a photon rate or time left polluted by the compile (the first run
    said '466 photons/s  21377 s left'), or stays silent while the kernel compiles."""
    monkeypatch.setattr(kernel_scene, "COMPILE_NOTE_AFTER", 0.05)
    delay = 1.0
    out = io.StringIO()
    progress = simulate.progress_printer(out, every=0.0)
    seen = []

    def show(done, total, seconds):
        seen.append(seconds)
        progress(done, total, seconds)

    show.note = progress.note
    r = simulate.run(_SlowFirstTrace(_kscene(tmp_path), delay), 2 * simulate.CHUNK, seed=1, threads=1, progress=show)
    lines = out.getvalue().splitlines()
    assert "compiling the kernel, first run only" in lines[0] and "s left" not in lines[0]
    assert all("compiling" not in line for line in lines[1:]) and len(lines) == 3
    assert r.seconds < delay and max(seen) < delay       # the rate and ETA are of tracing only


def test_a_ready_kernel_says_nothing(tmp_path):
    notes = []
    kscene = _kscene(tmp_path)
    simulate.compile_kernel(kscene)                      # compiled (or loaded) now
    assert simulate.compile_kernel(kscene, note=notes.append) >= 0 and notes == []


def test_a_precision_run_gives_no_time_left_before_its_first_sigma(tmp_path):
    """Before the first σ estimate a precision run's only end is its photon cap (1e10 by default): a
    countdown to it ('118 s left', '21377 s left') says nothing.  Breaks if the first lines count down to
    the cap, or if the later lines lose their time left."""
    out = io.StringIO()
    progress = simulate.progress_printer(out, every=0.0)
    simulate.run(_kscene(tmp_path), 10 ** 9, seed=1, threads=1, progress=progress, precision=0.01,
                 min_photons=2 * simulate.CHUNK)
    lines = [line for line in out.getvalue().splitlines() if "photons" in line]
    assert "first estimate still to come" in lines[0] and "s left" not in lines[0]
    assert len(lines) > 2 and "s left" in lines[-1]


def test_a_growth_step_says_how_long_the_kernel_compiled_in_it(tmp_path, monkeypatch):
    """A growth step whose organs need the kernel compiled (the first step with organ targets, once per machine)
    says how much of its time that was (``lpy-light grow`` prints it), and a step with the kernel ready says
    nothing."""
    import trimesh

    from lpy_light.plant.light import LightModel
    rad = ("void plastic grey\n0\n0\n5 .5 .5 .5 0 0\n\nvoid light lamp\n0\n0\n3 10 10 10\n\n"
           + box("grey", (0, 0, 0), (1000, 1000, 1100)) + lamp_rectangle("lamp", (500, 500), 100, 1000))
    model = LightModel(write_scene(tmp_path, rad, [(500, 500, 500, 50, 0, 0, 1)]), organs={"Leaf": {"reflectance": 0.5}},
                       lamp_flux=[1.0], plant_unit="mm", position=(500, 500, 0), photons=2_000)
    leaf = trimesh.creation.icosphere(subdivisions=1, radius=30.0).apply_translation((0, 0, 400))
    organs = model.organs_from_meshes({1: (leaf, {"reflectance": 0.5}, "Leaf")})
    model.run(organs)                                    # compiled (or loaded) now
    assert "compile_seconds" not in model.run(organs).extra
    monkeypatch.setattr(kernel_scene, "COMPILE_NOTE_AFTER", -1.0)   # now any readiness check counts as a compile
    assert model.run(organs).extra["compile_seconds"] > 0
