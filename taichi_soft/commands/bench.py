"""``bench``: the studies of taichi_soft.bench, written as CSV, PNG and Markdown."""
from __future__ import annotations

import sys

from ..errors import UserError
from .common import DEFAULT_OUT, EXIT_OK, EXIT_TASKS_FAILED, add_task_args, check_output_dir


def add_parser(sub):
    """The ``bench`` command's arguments on the subparsers ``sub``."""
    p_bench = sub.add_parser("bench", help="benchmarks: work-precision, stability, kernel speed, full report")
    p_bench.add_argument("study", choices=["accuracy", "precision", "stability", "speed", "memory", "report", "mesh",
                                           "energy", "contact"],
                         help="what to measure; precision: work-precision at equal error; report runs accuracy, "
                              "precision, stability, speed and memory and writes REPORT.md; mesh: the mesh-body "
                              "goals (build time, frame cost), MESH.md; energy: the implicit solvers' energy "
                              "matrix (terrains, stiffness, steps, two-body scenes), ENERGY.md; contact: a cube sliding on a cube "
                              "against mu g, and what body contact costs in the pile, CONTACT.md")
    p_bench.add_argument("--quick", action="store_true", help="tiny sizes: a few minutes on 2 cores (what CI runs)")
    p_bench.add_argument("--out", help="output folder (default docs/benchmarks, or out/benchmarks-quick with --quick)")
    add_task_args(p_bench)
    p_bench.set_defaults(func=cmd_bench)


def cmd_bench(args) -> int:
    """``bench accuracy|precision|stability|speed|memory|report``: measure and write CSV, PNG and Markdown (docs/benchmarks/REPORT.md)."""
    import time

    from .. import runtime
    from ..progress import CountBar
    from ..tasks import RETRIES, make_executor

    if args.study in ("speed", "memory", "mesh", "energy", "contact") and (args.workers is not None or args.scheduler is not None):
        why = ("its cases run in one process" if args.study in ("energy", "contact") else
               "one configuration at a time: its measurements need a quiet machine")
        raise UserError(f"bench {args.study} runs serially ({why}); --workers/--scheduler apply to the "
                        "accuracy, precision and stability sweeps")
    default = f"{DEFAULT_OUT}/benchmarks-quick" if args.quick else "docs/benchmarks"
    out_dir = check_output_dir(args.out or default, "--out")
    if args.study == "mesh":  # mesh-body goals: build time and frame cost (bench/meshbody.py)
        from ..bench import meshbody as mesh_bench

        runtime.init("cpu", "f64")
        result = mesh_bench.run(repeats=2 if args.quick else 5, frames=5 if args.quick else 20)
        out_dir.mkdir(parents=True, exist_ok=True)
        b = result["build"]
        print(f"build {mesh_bench.N}^3 body from {result['triangles']} triangles: {b['median_s']:.2f} s wall, "
              f"{b['cpu_median_s']:.2f} s CPU (goal 2 s)")
        for kind, f in result["frame"].items():
            print(f"frame mesh/cube at 1280x720, {kind}: " + (f["error"] if "error" in f else
                  f"{f['mesh_ms']:.1f} / {f['cube_ms']:.1f} ms = {f['ratio']:.2f}x (goal 1.5x)"))
        print(f"wrote {mesh_bench.write_report(result, out_dir)}")
        return EXIT_OK
    if args.study == "energy":  # the implicit solvers' energy matrix (bench/energy.py)
        return _energy(args, out_dir)
    if args.study == "contact":  # body-body sliding and cost (bench/contact.py)
        return _contact(args, out_dir)
    # Before any work: an unreachable --scheduler is refused here, in a few seconds.
    executor = make_executor(args.workers, args.scheduler) if args.study not in ("speed", "memory") else None
    out_dir.mkdir(parents=True, exist_ok=True)
    from ..bench import report, serial_studies, sweeps

    start = time.perf_counter()
    acc = stab = speed = mem = prec = None
    files = []
    try:
        if args.study in ("accuracy", "report"):
            acc = sweeps.run_accuracy(args.quick, executor)
            files += sweeps.write_accuracy(acc, out_dir)
        if args.study in ("precision", "report") and not (acc and acc["interrupted"]):
            prec = sweeps.run_precision(args.quick, executor)
            files += sweeps.write_precision(prec, out_dir)
        if args.study in ("stability", "report") and not any(r and r["interrupted"] for r in (acc, prec)):
            stab = sweeps.run_stability(args.quick, executor)
            files += sweeps.write_stability(stab, out_dir)
    finally:
        if executor is not None:
            executor.close()
    if args.study in ("speed", "report") and not any(r and r["interrupted"] for r in (acc, prec, stab)):
        runtime.init("cpu", "f64")  # speed_configs asks Taichi which backends this machine has
        bar = CountBar(1, "bench speed", unit="config")
        speed = serial_studies.run_speed(args.quick, lambda done, total, what: bar.update(done, what[:60], total=total))
        bar.close()
        files += serial_studies.write_speed(speed, out_dir)
    if args.study in ("memory", "report") and not any(r and r["interrupted"] for r in (acc, prec, stab, speed)):
        bar = CountBar(1, "bench memory", unit="size")
        mem = serial_studies.run_memory(args.quick, lambda done, total, what: bar.update(done, str(what)[:60], total=total))
        bar.close()
        files += serial_studies.write_memory(mem, out_dir)
    command = "python main.py bench " + args.study + (" --quick" if args.quick else "") + (f" --out {args.out}" if args.out else "")
    name = "REPORT.md" if args.study == "report" else f"{args.study.upper()}.md"
    md = report.write_report(out_dir, command, acc, stab, speed, time.perf_counter() - start, mem, name, prec)
    files.append(md.name)
    if acc:
        for case, data in acc["cases"].items():
            orders = ", ".join(f"{k} {v:.2f}" for k, v in data["orders"].items() if v is not None)
            print(f"fitted orders ({case}): {orders}")
    print(f"wrote {len(files)} files to {out_dir}: {md}")
    failed = {k: v for r in (acc, prec, stab) if r for k, v in r["failed"].items()}
    for key, err in failed.items():
        print(f"bench {args.study}: task {key} FAILED after {RETRIES + 1} attempts: {err}", file=sys.stderr)
    if any(r and r["interrupted"] for r in (acc, prec, stab, speed, mem)):
        return 130
    return EXIT_TASKS_FAILED if failed else EXIT_OK


def _energy(args, out_dir) -> int:
    """``bench energy``: every case in this process; energy.csv and ENERGY.md in ``out_dir``."""
    from ..bench import energy

    def report(result, verdict):
        print(next(line for line in verdict if line.startswith("**")))

    result = _in_process(args, out_dir, "Energy matrix", len(energy.cases(args.quick)), energy.run, energy.markdown,
                         lambda result: result["rows"], report)
    if result["interrupted"]:
        raise KeyboardInterrupt
    return EXIT_OK


def _contact(args, out_dir) -> int:
    """``bench contact``: the slides and the pile's cost in this process; contact.csv and CONTACT.md."""
    from ..bench import contact

    def rows(result):
        return ([{"study": "slide", **{k: v for k, v in r.items() if k != "relative_vx"}} for r in result["slide"]]
                + [{"study": "cost", **r} for r in result["cost"]])

    def report(result, _lines):
        for r in result["slide"]:
            print(f"slide {r['integrator']} mu={r['mu']:g}: {r['deceleration']:.2f} m/s^2 (mu g {r['mu_g']:.2f})")
        for r in result["cost"]:
            print(f"pile {r['integrator']}: contact on / off {r['ratio']:.2f}x")

    _in_process(args, out_dir, "Body-body contact", 1, contact.run, contact.markdown, rows, report)
    return EXIT_OK


def _in_process(args, out_dir, title: str, cases: int, run, markdown, rows, report) -> dict:
    """A study whose cases run in this process (``bench energy``, ``bench contact``): ``run(quick,
    progress)``, then <study>.csv (``rows(result)``) and <STUDY>.md (``markdown(result)`` under the
    command and the machine) in ``out_dir``; ``report(result, markdown lines)`` prints the verdict."""
    import time

    from .. import runtime
    from ..bench import machine
    from ..bench.files import write_csv, write_text
    from ..progress import CountBar

    runtime.init("cpu", "f64")
    out_dir.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    bar = CountBar(cases, f"bench {args.study}", unit="case")
    result = run(args.quick, lambda done, total, what: bar.update(done, what[:60], total=total))
    bar.close()
    command = f"python main.py bench {args.study}" + (" --quick" if args.quick else "") + (f" --out {args.out}" if args.out else "")
    verdict = markdown(result)
    lines = [f"# {title}", "", f"Command: `{command}` ({time.perf_counter() - start:.0f} s).", "", "Machine:",
             machine.markdown(machine.describe()), ""] + verdict
    write_csv(rows(result), out_dir / f"{args.study}.csv")
    write_text(out_dir / f"{args.study.upper()}.md", "\n".join(lines))
    report(result, verdict)
    print(f"wrote {args.study}.csv and {args.study.upper()}.md to {out_dir}")
    return result
