"""Where the kernel's compiled code spends a step, by source line: perf samples mapped through the JIT's line tables.

numba inlines every helper into one function (:func:`kernel.trace.trace_photons`), so ``perf report`` sees one
anonymous block of JIT code.  This script runs a step under ``perf record`` in a child process that compiles the
kernel with debug line tables (``NUMBA_DEBUGINFO=1``, in a cache of its own under ``--work``: ~5-10 min the first
time) and writes the entry point's object code and load address; each sample inside it is then mapped with
``addr2line -i`` to its chain of inlined calls, and summed by the call in ``trace_photons`` it comes from and by
the innermost lines.  Needs ``perf`` and ``addr2line`` (binutils).

    .venv/bin/python benchmarks/kernel_lines.py [--case nee-rose] [--steps 3] [--work /tmp/kernel-lines]

Cases as ``benchmarks/raw_embree.py --steps``'s (one thread).  The shares are of the samples inside
``trace_photons`` (Embree, libm and Python are outside it: ``perf report --sort dso`` on ``WORK/perf.data``).
"""
import argparse
import collections
import os
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent


def child(case, steps, work):
    """Run in the profiled process: warm the case, write trace_photons' objects, then ``steps`` steps."""
    sys.path.insert(0, str(HERE))
    import raw_embree
    from lpy_light.kernel.trace import trace_photons

    step = raw_embree.step_of(case, 3e5)
    step()
    for cres in trace_photons.overloads.values():
        addr = cres.library.get_pointer_to_function(cres.fndesc.llvm_func_name)
        (Path(work) / ("trace_photons_%x.o" % addr)).write_bytes(cres.library._get_compiled_object())
    for _ in range(steps):
        step()


def samples(work):
    """{(object, offset in its .ltext): samples} for the samples inside each trace_photons object."""
    objs = []
    for obj in Path(work).glob("trace_photons_*.o"):
        addr = int(obj.stem.split("_")[-1], 16)
        for line in subprocess.run(["nm", "-S", str(obj)], capture_output=True, text=True).stdout.splitlines():
            p = line.split()
            if len(p) == 4 and p[2] == "T" and "trace_photons" in p[3] and "cpython" not in p[3]:
                objs.append((obj, addr, int(p[0], 16), int(p[1], 16)))
    out = subprocess.run(["perf", "script", "-i", str(Path(work) / "perf.data"), "-F", "ip"], capture_output=True,
                         text=True).stdout
    counts = collections.Counter()
    for word in out.split():
        ip = int(word, 16)
        for obj, addr, value, size in objs:
            if addr <= ip < addr + size:
                counts[(obj, ip - addr + value)] += 1
    return counts


def chains(obj, offsets):
    """{offset: [(function, file:line) innermost first]} from ``addr2line -i``."""
    res = subprocess.run(["addr2line", "-a", "-i", "-f", "-e", str(obj), "-j", ".ltext"],
                         input="\n".join(hex(a) for a in offsets), capture_output=True, text=True).stdout.splitlines()
    out, cur, i = {}, None, 0
    while i < len(res):
        if res[i].startswith("0x"):
            cur = int(res[i], 16)
            out[cur] = []
            i += 1
        else:
            out[cur].append((res[i], os.path.basename(res[i + 1].split(" ")[0])))
            i += 2
    return out


def report(work, top=25) -> str:
    counts = samples(work)
    total = sum(counts.values())
    by_call, by_line = collections.Counter(), collections.Counter()
    for obj in {o for o, _ in counts}:
        offs = [a for o, a in counts if o == obj]
        for a, ch in chains(obj, offs).items():
            n = counts[(obj, a)]
            lines = [loc for _, loc in ch]
            by_call[lines[-1] if lines else "?"] += n           # the line of trace_photons the sample is under
            by_line[" < ".join(lines[:3]) if lines else "?"] += n
    out = ["%d samples inside trace_photons" % total, "", "by the call in trace_photons (kernel/trace.py line):"]
    out += ["%6.1f %%  %s" % (100 * n / total, k) for k, n in by_call.most_common(top)]
    out += ["", "by innermost line < its caller < theirs:"]
    out += ["%6.1f %%  %s" % (100 * n / total, k) for k, n in by_line.most_common(top)]
    return "\n".join(out)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", default="nee-rose")
    ap.add_argument("--steps", type=int, default=3)
    ap.add_argument("--work", default="/tmp/kernel-lines")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--report-only", action="store_true", help="map the samples of an earlier run")
    args = ap.parse_args(argv)
    if args.child:
        return child(args.case, args.steps, args.work)
    work = Path(args.work)
    if not args.report_only:
        work.mkdir(parents=True, exist_ok=True)
        for old in work.glob("trace_photons_*.o"):
            old.unlink()
        env = dict(os.environ, NUMBA_DEBUGINFO="1", NUMBA_CACHE_DIR=str(work / "numba-cache"))
        subprocess.run(["perf", "record", "-F", "999", "-o", str(work / "perf.data"), sys.executable, __file__,
                        "--child", "--case", args.case, "--steps", str(args.steps), "--work", str(work)],
                       env=env, check=True)
    print(report(work))


if __name__ == "__main__":
    sys.exit(main())
