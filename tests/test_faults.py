"""Faults: fuzzed Radiance input, interrupted runs, reproducibility, memory refusal."""
from __future__ import annotations

import csv
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lpy_light import cli
from lpy_light.estimators import memory
from lpy_light.run import simulate
from lpy_light.errors import InputError, LpyLightError, ResourceError
from lpy_light.chamber.radiance import parse_rad, read_rad
from lpy_light.chamber.scene import Physics, build_chamber, load_scene, resolve_scene
from lpy_light.chamber.sensors import DISC, Sensors
from scenes import box, lamp_rectangle, rad_polygon, write_scene

ROOT = Path(__file__).resolve().parents[1]

# ------------------------------------------------------------------------------------------
# Fuzzing the Radiance reader: whatever the bytes, it parses or raises InputError
VALID = ("void plastic grey\n0\n0\n5 0.5 0.5 0.5 0.05 0.1\n\nvoid light lamp\n0\n0\n3 10 10 10\n\n"
         "void trans sheet\n0\n0\n7 0.3 0.3 0.3 0 0 0.5 0.2\n\nvoid mirror glass2\n0\n0\n3 0.9 0.9 0.9\n\n"
         "void x skipped\n0\n0\n0\n\n"
         + box("grey", (0, 0, 0), (100, 100, 110))
         + lamp_rectangle("lamp", (50, 50), 10, 100)
         + rad_polygon("sheet", "diffuser", [(0, 0, 90), (100, 0, 90), (100, 100, 90), (0, 100, 90)])
         + "glass2 ring r1\n0\n0\n8 50 50 1 0 0 1 0 5\n\n"
         + "grey sphere ball\n0\n0\n4 30 30 30 5\n\n"
         + "grey cylinder pipe\n0\n0\n7 10 10 10 10 10 60 2\n\n"
         + "lamp cylinder tube1\n0\n0\n7 20 80 95 80 80 95 0.5\n\n"
         + "grey tube t2\n0\n0\n7 70 20 10 70 20 60 3\n\n"
         + "grey bubble b2\n0\n0\n4 70 70 30 4\n")
VALID_TOKENS = VALID.split()
ODD = ["nan", "NaN", "-nan", "inf", "-inf", "1e999", "-1e999", "1e-999", "-0", "+0", "0", "1", "-1", "3", "5", "7",
       "8", "9", "12", "99999999999999999999", "1e308", "-1e308", "1e12", "1e13", "4.9e-324", ".5", "5.", "1_0",
       "0x10", "1,5", "²", "٣", "!xform", "#", "\n", "void", "polygon", "plastic", "light", "glow", "trans",
       "mirror", "metal", "ring", "sphere", "cylinder", "tube", "bubble", "cone", "glass", "instance", "x", "grey",
       "lamp", "sheet", "glass2", "undefined", "\x00", "\xe9", "\ufeff", "\x0c", "\x1c", "\u2028", "\udce9"]
NUMERIC = re.compile(r"[-+]?[0-9.]+([eE][-+]?[0-9]+)?")
number = st.one_of(st.sampled_from(["nan", "inf", "-inf", "1e999", "-0", "0", "1e-320", "4.9e-324", "1e12", "1e13",
                                    "-1", "0.5", "2", "3", "1e300", "-1e300", "1e-300", ".", "1.", "+.5"]),
                   st.floats(allow_nan=True, allow_infinity=True).map(repr), st.integers(-3, 30).map(str))
token = st.one_of(st.sampled_from(ODD), st.sampled_from(VALID_TOKENS),
                  st.floats(allow_nan=True, allow_infinity=True).map(repr),
                  st.integers(-10, 10 ** 20).map(str), st.text(max_size=6))


@st.composite
def mutated(draw):
    """The valid file with a few token insertions, deletions and replacements (or a random stream)."""
    if draw(st.integers(0, 9)) == 0:
        return " ".join(draw(st.lists(token, max_size=60)))
    tokens = list(VALID_TOKENS)
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(["insert", "delete", "replace", "swap", "number", "number", "number"]))
        i = draw(st.integers(0, len(tokens)))
        if op == "number":        # a number for a number: the structure holds, the values are odd
            numeric = [k for k, tok in enumerate(tokens) if NUMERIC.fullmatch(tok)]
            if numeric:
                tokens[draw(st.sampled_from(numeric))] = draw(number)
        elif op == "insert":
            tokens.insert(i, draw(token))
        elif tokens and i < len(tokens):
            if op == "delete":
                del tokens[i]
            elif op == "replace":
                tokens[i] = draw(token)
            else:
                j = draw(st.integers(0, len(tokens) - 1))
                tokens[i], tokens[j] = tokens[j], tokens[i]
    sep = draw(st.sampled_from([" ", "\n", "\t", "\r\n"]))
    text = sep.join(tokens)
    if draw(st.integers(0, 4)) == 0:   # and sometimes cut it short
        text = text[:draw(st.integers(0, len(text)))]
    return text


def check_rad_text(text):
    """The property: parse (and build a chamber from what parses), or an InputError; nothing else."""
    try:
        prims = parse_rad(text, "fuzz.rad")
    except InputError as exc:
        assert exc.path == "fuzz.rad" and "\n" not in str(exc)
        return "refused by the reader"
    try:
        chamber = build_chamber(prims, bands=None, physics=Physics())
    except InputError as exc:
        assert "\n" not in str(exc)
        return "refused by the scene"
    assert np.isfinite(chamber.triangles).all() and np.isfinite(chamber.emitters.cdf).all()
    return "built"


def check_rad_bytes(tmp_path, data: bytes):
    path = tmp_path / "fuzz.rad"
    path.write_bytes(data)
    try:
        prims = read_rad(path)
    except InputError as exc:
        assert exc.path == str(path)
        return
    try:
        build_chamber(prims)
    except InputError:
        pass


FUZZ = settings(max_examples=300, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
FUZZ_SLOW = settings(max_examples=100_000, deadline=None, database=None,
                     suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])


def test_valid_file_builds():
    assert check_rad_text(VALID) == "built"


@pytest.mark.filterwarnings("error")      # a numpy warning is a fault too (it would print on stderr)
@FUZZ
@given(mutated())
def test_fuzz_rad_mutations(text):
    check_rad_text(text)


@pytest.mark.filterwarnings("error")
@FUZZ
@given(st.binary(max_size=300) | mutated().map(lambda t: t.encode("utf-8", "surrogateescape")))
def test_fuzz_rad_bytes(tmp_path, data):
    check_rad_bytes(tmp_path, data)


@pytest.mark.slow
@pytest.mark.filterwarnings("error")
@FUZZ_SLOW
@given(mutated())
def test_fuzz_rad_mutations_long(text):
    check_rad_text(text)


@pytest.mark.slow
@pytest.mark.filterwarnings("error")
@FUZZ_SLOW
@given(st.binary(max_size=2000) | mutated().map(lambda t: t.encode("utf-8", "surrogateescape")))
def test_fuzz_rad_bytes_long(tmp_path, data):
    check_rad_bytes(tmp_path, data)


@pytest.mark.filterwarnings("error")
@settings(max_examples=60, deadline=None, database=None)
@given(bands=st.lists(st.tuples(st.floats(300, 900), st.floats(0.5, 40)), min_size=1, max_size=4),
       one_sided=st.booleans(), lamps=st.sampled_from(["line", "lambertian"]),
       specular=st.sampled_from(["mirror", "phong"]), text=mutated())
def test_fuzz_scene_build(bands, one_sided, lamps, specular, text):
    """Parsed (fuzzed) geometry with random bands and physics: a chamber and a kernel scene, or InputError."""
    try:
        prims = parse_rad(text, "fuzz.rad")
        chamber = build_chamber(prims, bands=[(a, a + w) for a, w in bands],
                                physics=Physics(one_sided=one_sided, lamps=lamps, specular=specular))
    except InputError:
        return
    ks = simulate.KernelScene(chamber, "weighted")
    assert ks.n_bands == len(bands) and len(ks.tri_verts) <= len(chamber.triangles)


# ------------------------------------------------------------------------------------------
# Fuzzing SEC2's dialect and OBJ chambers: whole lines mutated (comments and line ends carry meaning there)
VALID_SEC2 = ("# chambre\n\nscale_factor 100\n\nvoid light lamp32w\n0\n0\n1\n0.32 0.32 0.32\n\n"
              "void plastic grey\n0\n0\n5\n0.5 0.5 0.5 0.1 0\n\n"
              + box("grey", (0, 0, 0), (100, 100, 110))
              + "lamp32w point_light neon1\n50 50 90 # centre\n#150 # longueur\n#0 0 1 # direction\n\n"
              + "lamp32w point ampoule\n20 20 80 1.5\n\nlamp32w point_light neon2 0 0 3 60 60 90\n")
SEC2_ODD = ["scale_factor", "scale_factor 0", "scale_factor 1000", "scale_factor nan", "point", "point_light",
            "spot_light", "lamp32w spot_light s", "12 5 2", "170", "1 0 1", "# centre", "150", "0 0 3", "1e999",
            "-1", "0", "lamp32w point_light n", "grey point_light n", "x point p", "#", "0.32", "\x00", "\xe9"]
VALID_OBJ = ("mtllib c.mtl\no room\nusemtl grey\n"
             + "".join("v %g %g %g\n" % (x, y, z) for z in (0, 110) for y in (0, 100) for x in (0, 100))
             + "vn 0 0 1\nf 1 2 4 3\nf 5 7 8 6\nf 1 5 6 2\ng wall\nf 3 4 8 7\nf -8//1 -4//1 -2//1 -6//1\n"
             "f 2 6 8 4\nusemtl lamp32w\nf 1 2 4\n")
OBJ_ODD = ["v", "v 1 2", "v 1 2 3", "v nan 0 0", "f", "f 1 2", "f 1 2 3", "f 0 1 2", "f -1 -2 -3", "f 1/2/3 4//5 6",
           "usemtl", "usemtl grey", "usemtl nope", "usemtl a b", "o", "g x y", "s 1", "curv 0 1", "foo", "#",
           "\\", "f 1 2 99", "v 1e999 0 0", "\x00", "\xe9"]


@st.composite
def mutated_lines(draw, valid, odd):
    """``valid`` with a few whole lines deleted, doubled, swapped or replaced, and tokens inside lines changed."""
    lines = valid.split("\n")
    for _ in range(draw(st.integers(1, 4))):
        i = draw(st.integers(0, len(lines) - 1)) if lines else 0
        op = draw(st.sampled_from(["delete", "double", "swap", "insert", "token", "token", "cut"]))
        if not lines:
            lines.append(draw(st.sampled_from(odd)))
        elif op == "delete":
            del lines[i]
        elif op == "double":
            lines.insert(i, lines[i])
        elif op == "swap":
            j = draw(st.integers(0, len(lines) - 1))
            lines[i], lines[j] = lines[j], lines[i]
        elif op == "insert":
            lines.insert(i, draw(st.sampled_from(odd) | token))
        elif op == "token":
            words = lines[i].split(" ")
            k = draw(st.integers(0, len(words)))
            words.insert(k, draw(st.sampled_from(odd) | token | number))
            if draw(st.booleans()) and len(words) > 1:
                del words[draw(st.integers(0, len(words) - 1))]
            lines[i] = " ".join(words)
        else:
            lines[i] = lines[i][:draw(st.integers(0, len(lines[i])))]
    return "\n".join(lines)


def check_sec2_text(text):
    """Parse and build (units resolved as a scene does), or an InputError of one line; nothing else."""
    from lpy_light.chamber.scene import in_unit
    try:
        prims = parse_rad(text, "fuzz.rad")
        build_chamber(in_unit(prims, "mm"), physics=Physics())
    except InputError as exc:
        assert "\n" not in str(exc) and (exc.path in (None, "fuzz.rad")), str(exc)
        return "refused"
    return "built"


def check_obj_text(text):
    from lpy_light.chamber.obj import parse_obj
    materials = parse_rad("void plastic grey 0 0 5 .5 .5 .5 0 0\nvoid light lamp32w 0 0 3 1 1 1\n"
                          "lamp32w point_light n 50 50 50\n", "m.rad")
    try:
        prims = parse_obj(text, "fuzz.obj")
        chamber = build_chamber(list(materials) + list(prims), physics=Physics())
    except InputError as exc:
        assert "\n" not in str(exc) and exc.path in (None, "fuzz.obj", "m.rad"), str(exc)
        return "refused"
    assert np.isfinite(chamber.triangles).all()
    return "built"


def test_valid_sec2_and_obj_build():
    assert check_sec2_text(VALID_SEC2) == "built" and check_obj_text(VALID_OBJ) == "built"
    assert parse_rad(VALID_SEC2).sec2


@pytest.mark.filterwarnings("error")
@FUZZ
@given(mutated_lines(VALID_SEC2, SEC2_ODD))
def test_fuzz_sec2_dialect(text):
    check_sec2_text(text)


@pytest.mark.filterwarnings("error")
@FUZZ
@given(mutated_lines(VALID_OBJ, OBJ_ODD))
def test_fuzz_obj(text):
    check_obj_text(text)


@pytest.mark.slow
@pytest.mark.filterwarnings("error")
@FUZZ_SLOW
@given(mutated_lines(VALID_SEC2, SEC2_ODD) | mutated_lines(VALID_OBJ, OBJ_ODD).map(lambda t: "OBJ" + t))
def test_fuzz_sec2_and_obj_long(text):
    if text.startswith("OBJ"):
        check_obj_text(text[3:])
    else:
        check_sec2_text(text)


# ------------------------------------------------------------------------------------------
# Interrupted runs: SIGTERM and Ctrl-C give partial, correctly normalised results
def _start_and_signal(out, signals, threads=2):
    """Start ``lpy-light run angers`` with a 1e10 cap, wait for tracing to start, send ``signals``."""
    proc = subprocess.Popen([sys.executable, "-m", "lpy_light", "run", "angers", "--photons", "1e10", "--seed", "5",
                             "--threads", str(threads), "--out", str(out)],
                            stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=ROOT)
    lines = []
    deadline = time.monotonic() + 120
    for line in proc.stderr:           # progress lines come after each finished chunk
        lines.append(line)
        if "photons/s" in line and "/10000000000 photons" in line:
            break
        assert time.monotonic() < deadline, "".join(lines)
    for sig in signals:
        proc.send_signal(sig)
    rest = proc.stderr.read()
    code = proc.wait(timeout=120)
    return code, "".join(lines) + rest


def _check_partial(out, stderr, code):
    assert code == 130, stderr
    assert "Traceback" not in stderr and "PARTIAL" in stderr, stderr
    assert sorted(p.name for p in out.iterdir()) == ["sensors.csv", "summary.json"]   # no temporary files left
    summary = json.loads((out / "summary.json").read_text())
    n = summary["photons"]
    assert summary["partial"] is True and 0 < n < 10 ** 10 and n % simulate.CHUNK == 0
    closure = summary["energy_closure"]["655-665"]
    assert closure["emitted"] == n and abs(closure["residual"]) <= 5 * closure["residual_std"] + 1e-9
    rows = list(csv.DictReader(open(out / "sensors.csv")))
    assert len(rows) == 240
    # normalised for the n photons traced: the chunks form a prefix of the run, so a full run of n photons
    # with the same seed gives the very same numbers
    full = out.parent / (out.name + "-full")
    assert cli.main(["run", "angers", "--photons", str(n), "--seed", "5", "--threads", "1", "--out", str(full),
                     "--quiet"]) == 0
    assert (full / "sensors.csv").read_text() == (out / "sensors.csv").read_text()
    assert all(np.isfinite(float(r["ppfd"])) for r in rows)
    return summary


def test_sigterm_writes_partial_results(tmp_path):
    code, stderr = _start_and_signal(tmp_path / "out", [signal.SIGTERM])
    _check_partial(tmp_path / "out", stderr, code)


def test_ctrl_c_writes_partial_results(tmp_path):
    code, stderr = _start_and_signal(tmp_path / "out", [signal.SIGINT])
    _check_partial(tmp_path / "out", stderr, code)


def test_two_ctrl_c_still_write_partial_results(tmp_path):
    code, stderr = _start_and_signal(tmp_path / "out", [signal.SIGINT, signal.SIGINT], threads=1)
    _check_partial(tmp_path / "out", stderr, code)


def test_keyboard_interrupt_in_run_keeps_a_whole_prefix(tmp_path):
    """simulate.run (the API, e.g. inside L-Py) turns Ctrl-C into a partial result of whole chunks."""
    rad = ("void plastic grey\n0\n0\n5 .5 .5 .5 0 0\n\nvoid light lamp\n0\n0\n3 10 10 10\n\n"
           + box("grey", (0, 0, 0), (1000, 1000, 1100)) + lamp_rectangle("lamp", (500, 500), 100, 1000))
    chamber = load_scene(write_scene(tmp_path, rad, [(500, 500, 500, 50, 0, 0, 1)]))
    ks = simulate.KernelScene(chamber, "weighted")
    calls = []

    def progress(done, total, seconds):
        calls.append(done)
        if len(calls) == 3:
            raise KeyboardInterrupt

    r = simulate.run(ks, 10 * simulate.CHUNK, seed=2, threads=2, progress=progress)
    assert r.partial and r.interrupted and r.photons == 3 * simulate.CHUNK
    full = simulate.run(ks, 3 * simulate.CHUNK, seed=2, threads=1)
    np.testing.assert_array_equal(r.tally, full.tally)
    np.testing.assert_array_equal(r.tally_prod, full.tally_prod)


def test_results_are_written_atomically_and_readable(tmp_path, monkeypatch):
    from lpy_light.run import results
    target = tmp_path / "a.txt"
    results.atomic_write(target, "one\n")
    assert target.read_text() == "one\n" and oct(target.stat().st_mode & 0o777) != oct(0o600)
    real_replace = os.replace

    def failing(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", failing)
    with pytest.raises(OSError):
        results.atomic_write(target, "two\n")
    monkeypatch.setattr(os, "replace", real_replace)
    assert target.read_text() == "one\n" and [p.name for p in tmp_path.iterdir()] == ["a.txt"]


# ------------------------------------------------------------------------------------------
# Reproducibility: the seed alone decides the numbers
@pytest.fixture(scope="module")
def room(tmp_path_factory):
    d = tmp_path_factory.mktemp("room")
    rad = ("void plastic grey\n0\n0\n5 .6 .6 .6 .1 0\n\nvoid mirror m\n0\n0\n3 .9 .9 .9\n\n"
           "void light lamp\n0\n0\n3 10 10 10\n\n"
           + box("grey", (0, 0, 0), (1000, 1000, 1100)) + lamp_rectangle("lamp", (500, 500), 100, 1000)
           + rad_polygon("m", "mirror1", [(990, 100, 100), (990, 900, 100), (990, 900, 900), (990, 100, 900)]))
    (d / "solid.rad").write_text("void plastic pot\n0\n0\n5 .2 .2 .2 0 0\n\npot sphere pot1\n0\n0\n4 400 600 200 80\n")
    scene = write_scene(d, rad, [(500, 500, 500, 50, 0, 0, 1), (300, 700, 300, 40, 1, 0, 1)],
                        'solid_sensors = "solid.rad"\nbands = [[400, 500], [500, 600], [600, 700]]\n')
    return load_scene(scene)


@pytest.mark.parametrize("estimator", ["weighted", "nee", "analog"])
def test_same_seed_same_numbers_on_1_or_2_threads(room, estimator):
    ks = simulate.KernelScene(room, estimator=estimator)
    n = 2 * simulate.CHUNK + 123
    r1 = simulate.run(ks, n, seed=11, threads=1)
    r2 = simulate.run(ks, n, seed=11, threads=2)
    r3 = simulate.run(ks, n, seed=12, threads=2)
    for name in ("tally", "tally_prod", "counters", "nee_stats"):
        np.testing.assert_array_equal(getattr(r1, name), getattr(r2, name), err_msg=name)
    assert r1.tally[: ks.n_sensors + 2 * ks.n_receivers].sum() > 0
    assert not np.array_equal(r1.tally, r3.tally)


def test_same_seed_same_files_from_the_command_line(tmp_path, capsys):
    scene = write_scene(tmp_path / "s", "void plastic grey\n0\n0\n5 .6 .6 .6 0 0\n\nvoid light lamp\n0\n0\n3 1 1 1\n\n"
                        + box("grey", (0, 0, 0), (1000, 1000, 1100)) + lamp_rectangle("lamp", (500, 500), 100, 1000),
                        [(500, 500, 500, 50, 0, 0, 1)])
    texts = []
    for threads, seed in [(1, 3), (2, 3), (2, 4)]:
        out = tmp_path / ("o%d%d" % (threads, seed))
        assert cli.main(["run", str(scene), "--photons", "40000", "--seed", str(seed), "--threads", str(threads),
                         "--estimator", "nee", "--out", str(out), "--quiet"]) == 0
        texts.append((out / "sensors.csv").read_text())
    assert texts[0] == texts[1] and texts[0] != texts[2]


# ------------------------------------------------------------------------------------------
# Memory: refused up front, with the numbers
def _huge_chamber(n_sensors, n_bands):
    rad = ("void plastic grey\n0\n0\n5 .5 .5 .5 0 0\n\nvoid light lamp\n0\n0\n3 10 10 10\n\n"
           + box("grey", (0, 0, 0), (1000, 1000, 1100)) + lamp_rectangle("lamp", (500, 500), 100, 1000))
    rng = np.random.default_rng(0)
    sensors = Sensors(np.full(n_sensors, DISC, np.int32), rng.uniform(100, 900, (n_sensors, 3)),
                      np.tile([0.0, 0, 1], (n_sensors, 1)), np.full(n_sensors, 5.0), np.zeros((n_sensors, 4, 3)),
                      [("synthetic", i) for i in range(n_sensors)])
    bands = [(300.0 + i, 301.0 + i) for i in range(n_bands)]
    return build_chamber(parse_rad(rad, "huge.rad"), sensors, bands=bands)


def test_huge_tallies_are_refused_before_allocating():
    chamber = _huge_chamber(100_000, 400)     # tally_prod alone: 100k rows x 400 x 400 x 8 bytes = 128 GB
    with pytest.raises(ResourceError) as info:
        simulate.KernelScene(chamber, "weighted")
    msg = str(info.value)
    assert isinstance(info.value, LpyLightError)
    assert "needs about" in msg and "GiB available" in msg and "x 400 band(s) x 400 band(s)" in msg
    assert "fewer bands, sensors or threads" in msg


def test_memory_estimate_grows_with_threads_bands_rows():
    small = simulate.memory_estimate(300, 12, 1)
    for threads in (1, 2, 8, 64):     # two chunks in flight per thread, the sum, the next sum, 3 for covariances
        big = simulate.memory_estimate(300, 12, threads)
        assert big["tallies"] == small["tally_set"] * (2 * threads + 5)
    assert simulate.memory_estimate(300, 24, 1)["tallies"] > 3.8 * small["tallies"]
    assert simulate.memory_estimate(600, 12, 1)["tallies"] > 1.9 * small["tallies"]
    assert small["tally_set"] == 8 * (300 * 12 * 13 + simulate.N_COUNTERS)
    assert simulate.memory_estimate(0, 1, 1, triangles=10 ** 6)["geometry"] >= 10 ** 8


def test_run_checks_memory_for_its_thread_count(room, monkeypatch):
    ks = simulate.KernelScene(room, "weighted")
    one = simulate.memory_estimate(ks.n_rows, ks.n_bands, 1, n_stats=len(ks.materials) + len(ks.emit_nee))
    monkeypatch.setattr(memory, "available_memory", lambda: int(1.5 * one["total"] / memory.MEMORY_SHARE))
    simulate.run(ks, 1000, threads=1)                                   # fits
    with pytest.raises(ResourceError, match="for 64 thread"):
        simulate.run(ks, 64 * simulate.CHUNK, threads=64)               # 64 threads' chunks do not


def test_command_line_refuses_with_one_line(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(memory, "available_memory", lambda: 1 << 20)   # 1 MiB left
    scene = write_scene(tmp_path / "s", "void plastic grey\n0\n0\n5 .6 .6 .6 0 0\n\nvoid light lamp\n0\n0\n3 1 1 1\n\n"
                        + box("grey", (0, 0, 0), (1000, 1000, 1100)) + lamp_rectangle("lamp", (500, 500), 100, 1000),
                        [(500, 500, 500, 50, 0, 0, 1)] * 300, "bands = %r\n" % [[400 + 10 * i, 410 + 10 * i]
                                                                                for i in range(30)])
    out = tmp_path / "out"
    code = cli.main(["run", str(scene), "--photons", "1000", "--out", str(out), "--quiet"])
    lines = capsys.readouterr().err.splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("lpy-light: error: this scene needs about")
    assert "0.000977 GiB available" in lines[0] and not out.exists()


def test_available_memory_is_known_here():
    free = memory.available_memory()
    assert free is None or free > 0


# ------------------------------------------------------------------------------------------
# The other readers, fuzzed a little: sensors, optical tables, specularities, spectrum, scene TOML
def _mutate_text(valid):
    pieces = st.sampled_from([",", ";", "\n", "\r", " ", '"', "nan", "inf", "-", "1e999", "0", "-1", "1,5", "\x00",
                              "\ufeff", "\xe9", "[", "]", "=", "{", "#", "'", "X", "x0", "[[", "]]", "true"])

    @st.composite
    def strategy(draw):
        text = valid
        for _ in range(draw(st.integers(1, 5))):
            i = draw(st.integers(0, len(text)))
            j = draw(st.integers(i, min(len(text), i + 8)))
            text = text[:i] + draw(st.one_of(pieces, st.text(max_size=4))) + text[j:]
        return text.encode("utf-8", "surrogatepass")
    return st.one_of(strategy(), st.binary(max_size=200))


def _readers():
    from lpy_light.chamber.optical import read_specularities, read_table
    from lpy_light.chamber.scene import load_scene
    from lpy_light.chamber.sensors import read_sensors
    from lpy_light.chamber.units import read_lamp_spectrum
    return {
        "sensors.csv": (read_sensors, "X,Y,Z,rayon_capteur,Xnorm,Ynorm,Znorm\n1,2,3,4,0,0,1\n5,6,7,8,0,1,0\n"),
        "quads.csv": (read_sensors, "x0,y0,z0,x1,y1,z1,x2,y2,z2,x3,y3,z3\n0,0,0,1,0,0,1,1,0,0,1,0\n"),
        "table.csv": (read_table, '"lambda";"moy"\n600;0,5\n601;0,25\n602;1,0\n'),
        "spec.csv": (read_specularities, "material,specularity\nwall,0.1\nfloor,0,2\n"),
        "spectrum.txt": (read_lamp_spectrum, "wl value\n600 0.5\n602 0.25\n"),
        "scene.toml": (load_scene, 'geometry = "g.rad"\nunit = "mm"\nbands = [[655, 665]]\n[physics]\nmax_depth = 5\n'),
    }


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("name", list(_readers()))
def test_fuzz_other_readers(tmp_path, name):
    reader, valid = _readers()[name]
    (tmp_path / "g.rad").write_text("void light l 0 0 3 1 1 1\nl polygon p 0 0 9 0 0 0 1 0 0 1 1 0\n")

    @settings(max_examples=150, deadline=None, database=None, suppress_health_check=list(HealthCheck))
    @given(_mutate_text(valid))
    def check(data):
        path = tmp_path / name
        path.write_bytes(data)
        try:
            reader(path)
        except InputError as exc:
            assert exc.path is not None and "\n" not in str(exc)

    check()
