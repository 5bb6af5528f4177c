"""Real robot models dropped onto the ground: does the implicit stepper take them as loaded?

Question: of the URDFs of example-robot-data (PyPI 6.0.0, `pip install ".[models]"`), which does
the stepper accept as DART loads them (meshes, joint friction, mimic joints, zero-mass links), and
what happens in the first fraction of a second when each falls onto a ground box, next to DART's
own stepper on the same model with its original meshes?

What is run, per URDF: DART's loader (package:// resolved with addPackageDirectory) with a
floating root; the model placed 5 cm above a ground box (its lowest collision point), gravity -z;
its <mimic> relations read with ic.urdf_mimic_joints. Then, alternately, one implicit step and
one DART step (interleaved, so the machine's drifts hit both), h = 1e-3, for --duration of
simulated time or until --budget seconds of implicit wall time.

Each model runs in its own process, --workers at once; each worker's BLAS gets its share of
the cores (OPENBLAS_NUM_THREADS = cores / workers, unless set: _share_cores).

One row per model: has collision geometry, accepted (or the refusal's sentence), steps done,
retried steps (substeps > 1), failure (StepFailure's message), deepest penetration reported by a
contact (gap < 0), median and max implicit time per step and the median ratio to DART's, root
height at the end for both. Written to comparisons/out/real_models.csv and printed; the summary
line counts accepted / with collision geometry.

--hulls instead prints, per collision mesh the models use (with their URDF scale), the exact
hull's facet planes, the simplified hull's planes (what one evaluation of it costs: one dot product
per plane, and each plane is a multiplier of a pair's MCP), its measured outward error against the
tolerance max(1 mm, 1 % of the mesh's size), and the time to build it; then the worst.

Run: python -m comparisons.real_models [--duration 0.3] [--budget 60] [--workers 2] [--only ur5,...]
                                       [--order 2]   (to real_models_order2.csv / .png)
     python -m comparisons.real_models --hulls
     python -m comparisons.real_models --plot-only    (the PNG from the last CSV)
"""
from __future__ import annotations

import argparse
import csv
import glob
import math
import os
import time
import traceback

import numpy as np

OUT = os.path.join(os.path.dirname(__file__), "out")
H = 1e-3


def robots_root():
    """example-robot-data's share directory (the PyPI wheel installs it under cmeel.prefix)."""
    import sysconfig
    root = os.path.join(sysconfig.get_paths()["purelib"], "cmeel.prefix", "share", "example-robot-data")
    if not os.path.isdir(os.path.join(root, "robots")):
        raise SystemExit("example-robot-data is not installed: pip install '.[models]'")
    return root


def urdfs(root):
    return sorted(glob.glob(os.path.join(root, "robots", "**", "*.urdf"), recursive=True))


def _load(path, root):
    import dartpy as dart
    loader = dart.utils.DartLoader()
    loader.addPackageDirectory("example-robot-data", root)
    for d in glob.glob(os.path.join(root, "robots", "*")):
        loader.addPackageDirectory(os.path.basename(d), d)
    return loader.parseSkeleton(path)


def _collision_nodes(skel):
    nodes = []
    for b in range(skel.getNumBodyNodes()):
        body = skel.getBodyNode(b)
        for s in range(body.getNumShapeNodes()):
            node = body.getShapeNode(s)
            if node.hasCollisionAspect():
                nodes.append(node)
    return nodes


def _lowest_point(nodes):
    low = math.inf
    for node in nodes:
        box = node.getShape().getBoundingBox()
        lo, hi = np.asarray(box.getMin()), np.asarray(box.getMax())
        T = node.getWorldTransform().matrix()
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        low = min(low, float((corners @ T[:3, :3].T + T[:3, 3])[:, 2].min()))
    return low


def _world(path, root):
    import dartpy as dart
    skel = _load(path, root)
    if skel is None:
        return None, None, None
    world = dart.simulation.World()
    world.setTimeStep(H)
    world.setGravity([0.0, 0.0, -9.81])
    world.addSkeleton(skel)
    nodes = _collision_nodes(skel)
    low = _lowest_point(nodes) if nodes else 0.0
    ground = dart.dynamics.Skeleton("ground")
    _, gb = ground.createWeldJointAndBodyNodePair()
    gn = gb.createShapeNode(dart.dynamics.BoxShape([20.0, 20.0, 0.2]))
    T = dart.math.Isometry3()
    T.set_translation([0.0, 0.0, low - 0.05 - 0.1])
    gn.setRelativeTransform(T)
    gn.createCollisionAspect()
    world.addSkeleton(ground)
    return world, skel, nodes


def _empty_row(path, root) -> dict:
    name = os.path.relpath(path, os.path.join(root, "robots"))
    return {"model": name, "collision": False, "accepted": False, "refusal": "", "steps": 0, "retried": 0,
           "failure": "", "deepest_mm": 0.0, "median_ms": math.nan, "max_ms": math.nan, "ratio": math.nan,
           "root_z": math.nan, "root_z_dart": math.nan, "bodies": 0, "dofs": 0}


def run_model(path, root, duration, budget, order=1, progress=None) -> dict:
    """One model's row, stepped by StepperOptions(order=order). progress (a shared array of 2, or None): the steps done and which stepper
    is running (0 implicit, 1 DART), for the row of a process that dies mid-step (run_isolated)."""
    import implicit_contact as ic
    row = _empty_row(path, root)
    try:
        world, skel, nodes = _world(path, root)
        if world is None:
            row["refusal"] = "DART could not load it"
            return row
        row["collision"], row["bodies"], row["dofs"] = bool(nodes), skel.getNumBodyNodes(), skel.getNumDofs()
        if not nodes:
            return row
        native, nskel, _ = _world(path, root)
        try:
            stepper = ic.ImplicitContactStepper(world, mimic=ic.urdf_mimic_joints(path),
                                                options=ic.StepperOptions(order=order))
        except ValueError as exc:
            row["refusal"] = str(exc)[:300]
            return row
        row["accepted"] = True
        ti, tn = [], []
        spent = 0.0
        for _ in range(int(round(duration / H))):
            if progress is not None:
                progress[0], progress[1] = row["steps"], 0
            t0 = time.perf_counter()
            try:
                report = stepper.step()
            except ic.StepFailure as exc:
                row["failure"] = str(exc)[:300]
                break
            t1 = time.perf_counter()
            if progress is not None:
                progress[1] = 1
            native.step()
            t2 = time.perf_counter()
            ti.append(t1 - t0)
            tn.append(t2 - t1)
            spent += t1 - t0
            row["steps"] += 1
            row["retried"] += int(report.substeps > 1)
            gaps = [c.gap for c in report.contacts if c.p_n > 0.0]
            if gaps:
                row["deepest_mm"] = max(row["deepest_mm"], -1e3 * min(gaps))
            if spent > budget:
                break
        if ti:
            row["median_ms"], row["max_ms"] = 1e3 * float(np.median(ti)), 1e3 * float(np.max(ti))
            row["ratio"] = float(np.median(ti) / np.median(tn))
        row["root_z"] = float(skel.getBodyNode(0).getWorldTransform().translation()[2])
        row["root_z_dart"] = float(nskel.getBodyNode(0).getWorldTransform().translation()[2])
    except Exception as exc:                       # anything else is a defect: reported, not hidden
        row["failure"] = "EXCEPTION " + "".join(traceback.format_exception_only(type(exc), exc)).strip()[:300]
    return row


BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def _share_cores(workers):
    """Give each worker process its share of the cores for BLAS (numpy's and scipy's OpenBLAS,
    which the dense solves of a robot's 100-200 unknowns call), unless the user set it: the
    workers are spawned after this and read it when they import numpy. Without it, 2 workers on 2
    cores ran 2 OpenBLAS threads each: measured 2026-12-06 with --workers 2, talos_reduced_box's
    median step 7.2 ms (3.1 ms with one BLAS thread a worker, as with one worker alone) and
    tiago_no_hand cut by the budget at t = 0.48 s (with one thread a worker it completes 1 s)."""
    if not any(v in os.environ for v in BLAS_THREAD_VARIABLES):
        os.environ["OPENBLAS_NUM_THREADS"] = str(max(1, (os.cpu_count() or 1) // workers))


def _child(conn, target, args):
    conn.send(target(*args))
    conn.close()


def run_isolated(jobs, workers, crashed, on_row):
    """Runs target(*args, progress) for each (target, args) of jobs, each in its own process
    (spawn), at most `workers` at once, and calls on_row with each result as it comes. DART's
    own step segfaults in FCL on some models (example-robot-data's g1_29dof_with_hand between
    t = 0.9 and 1 s, a null pointer in libfcl, measured at d6a9e99): a process that dies costs
    its row only; on_row then gets crashed(args, progress, exitcode)."""
    import multiprocessing
    import multiprocessing.connection
    ctx = multiprocessing.get_context("spawn")
    pending, running = list(jobs), []
    while pending or running:
        while pending and len(running) < workers:
            target, args = pending.pop(0)
            progress = ctx.Array("d", [0.0, -1.0], lock=False)
            recv, send = ctx.Pipe(duplex=False)
            proc = ctx.Process(target=_child, args=(send, target, (*args, progress)))
            proc.start()
            send.close()
            running.append((proc, recv, args, progress))
        ready = multiprocessing.connection.wait([r for _, r, _, _ in running])
        for item in [it for it in running if it[1] in ready]:
            proc, recv, args, progress = item
            try:
                result = recv.recv()
            except EOFError:                        # the process died before it could answer
                proc.join()
                result = crashed(args, progress, proc.exitcode)
            else:
                proc.join()
            recv.close()
            running.remove(item)
            on_row(result)


def _crashed_row(args, progress, exitcode) -> dict:
    path, root = args[0], args[1]
    row = _empty_row(path, root)
    row["collision"] = row["accepted"] = progress[1] >= 0     # it had begun stepping: it was accepted
    row["steps"] = int(progress[0])
    who = {0.0: "the implicit step", 1.0: "DART's own step"}.get(progress[1], "loading the model")
    row["failure"] = (f"CRASH: the process died (exit code {exitcode}) in {who} after {int(progress[0])} "
                      f"steps; the row's other figures are lost")
    return row


def hull_table(paths, root):
    """The --hulls table (module docstring); returns its rows."""
    from implicit_contact import hulls
    seen, rows = set(), []
    for path in paths:
        skel = _load(path, root)
        if skel is None:
            continue
        for node in _collision_nodes(skel):
            shape = node.getShape()
            if shape.getType() != "MeshShape":
                continue
            key = (shape.getMeshPath(), tuple(np.round(np.asarray(shape.getScale(), float), 12)))
            if key in seen or not os.path.exists(key[0]):
                continue
            seen.add(key)
            t0 = time.perf_counter()
            try:
                hull = hulls.mesh_hull(key[0], key[1])
            except ValueError as exc:
                print(f"{os.path.relpath(key[0], root):70s} refused: {exc}")
                continue
            rows.append((os.path.relpath(key[0], root), hull, time.perf_counter() - t0))
            r = rows[-1]
            print(f"{r[0][-70:]:70s} vertices {hull.vertices:6d} facet planes {hull.exact_planes:5d} -> "
                  f"{len(hull.normals):4d} planes, error {1e3 * hull.error:7.3f} mm of {1e3 * hull.tolerance:7.3f} mm, "
                  f"{r[2]:.3f} s", flush=True)
    if rows:
        planes = np.array([len(r[1].normals) for r in rows])
        exact = np.array([r[1].exact_planes for r in rows])
        ratio = np.array([r[1].error / r[1].tolerance for r in rows])
        worst = rows[int(np.argmax(ratio))]
        print(f"\n{len(rows)} meshes: facet planes median {np.median(exact):.0f}, p90 {np.percentile(exact, 90):.0f}, "
              f"max {exact.max()}; simplified median {np.median(planes):.0f}, p90 {np.percentile(planes, 90):.0f}, "
              f"max {planes.max()}; worst error {worst[1].error * 1e3:.3f} mm of {worst[1].tolerance * 1e3:.3f} mm "
              f"({worst[0]}); every mesh within its tolerance: {bool((ratio <= 1.0).all())}")
    return rows


def plot(rows, path):
    """comparisons/out/real_models.png: per model with collision geometry, how far it got (steps
    done) coloured by outcome, and its median step over DART's."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    col = [r for r in rows if str(r["collision"]) == "True"]
    names = [os.path.splitext(os.path.basename(r["model"]))[0] for r in col]
    steps = [int(r["steps"]) for r in col]
    ratio = [float(r["ratio"]) for r in col]
    colour = ["grey" if str(r["accepted"]) != "True" else "tab:red" if r["failure"] else
              "tab:green" if int(r["steps"]) >= max(steps) else "tab:orange" for r in col]
    fig, ax = plt.subplots(1, 2, figsize=(12, 0.22 * len(col) + 1.5), sharey=True)
    y = np.arange(len(col))
    ax[0].barh(y, steps, color=colour)
    ax[0].set_yticks(y, names, fontsize=7)
    ax[0].invert_yaxis()
    ax[0].set_xlabel(f"steps done at h = {H:g} s (green: all, orange: cut by the time budget, red: StepFailure, grey: refused)")
    ax[1].barh(y, ratio, color=colour)
    ax[1].axvline(30.0, color="k", ls="--", lw=0.8)
    ax[1].set_xscale("log")
    ax[1].set_xlabel("median implicit step / DART's (dashed: 30x)")
    fig.suptitle("example-robot-data dropped onto a ground box: implicit stepper against DART")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=0.3, help="simulated seconds per model")
    parser.add_argument("--budget", type=float, default=60.0, help="implicit wall seconds per model")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--only", default="", help="comma-separated substrings of model paths")
    parser.add_argument("--order", type=int, default=1, choices=(1, 2), help="StepperOptions(order=...)")
    parser.add_argument("--hulls", action="store_true", help="the per-mesh hull table instead")
    parser.add_argument("--plot-only", action="store_true", help="draw the PNG from the last CSV")
    args = parser.parse_args(argv)
    name = "real_models" if args.order == 1 else f"real_models_order{args.order}"
    if args.plot_only:
        with open(os.path.join(OUT, name + ".csv")) as f:
            plot(list(csv.DictReader(f)), os.path.join(OUT, name + ".png"))
        return
    root = robots_root()
    paths = urdfs(root)
    if args.only:
        keys = args.only.split(",")
        paths = [p for p in paths if any(k in p for k in keys)]
    if args.hulls:
        hull_table(paths, root)
        return
    rows = []

    def on_row(row):
        rows.append(row)
        _print_row(row)

    workers = max(args.workers, 1)
    _share_cores(workers)
    run_isolated([(run_model, (p, root, args.duration, args.budget, args.order)) for p in paths], workers,
                 _crashed_row, on_row)
    rows.sort(key=lambda r: r["model"])
    os.makedirs(OUT, exist_ok=True)
    with open(os.path.join(OUT, name + ".csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    plot([{k: str(v) for k, v in r.items()} for r in rows], os.path.join(OUT, name + ".png"))
    col = [r for r in rows if r["collision"]]
    acc = [r for r in col if r["accepted"]]
    done = [r for r in acc if not r["failure"] and r["steps"] >= int(round(args.duration / H))]
    failed = [r for r in acc if r["failure"] and not r["failure"].startswith("CRASH")]
    crashed = [r for r in rows if r["failure"].startswith("CRASH")]
    print(f"\n{len(rows)} URDFs, {len(col)} with collision geometry, {len(acc)} accepted "
          f"({100 * len(acc) / max(len(col), 1):.0f} %), {len(done)} completed {args.duration} s, "
          f"{len(failed)} failed, {sum(1 for r in acc if not r['failure'] and r not in done)} cut by the budget, "
          f"{len(crashed)} crashed")
    for r in crashed:
        print(f"crashed {r['model']}: {r['failure']}")
    if acc:
        ratios = np.array([r["ratio"] for r in acc if math.isfinite(r["ratio"])])
        if len(ratios):
            print(f"median step / DART's: median {np.median(ratios):.1f}x, max {ratios.max():.1f}x; "
                  f"deepest penetration {max(r['deepest_mm'] for r in acc):.3g} mm")
    for r in col:
        if not r["accepted"]:
            print(f"refused {r['model']}: {r['refusal']}")


def _print_row(r):
    state = ("no collision" if not r["collision"] else "REFUSED" if not r["accepted"]
             else ("FAILED" if r["failure"] else "ok"))
    print(f"{r['model']:60s} {state:12s} steps {r['steps']:4d} retried {r['retried']:3d} "
          f"median {r['median_ms']:8.2f} ms max {r['max_ms']:8.1f} ms ratio {r['ratio']:7.1f} "
          f"deepest {r['deepest_mm']:.3g} mm {r['failure'][:80]}", flush=True)


if __name__ == "__main__":
    main()
